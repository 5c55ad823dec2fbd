"""Episode pictures: the segmentation overlay shows the segmenter's classes
in colours that stand out from the plant's own."""
import numpy as np

from lmap_drake.evaluation.figures import OVERLAY_COLORS, Overlay
from lmap_drake.labels import BACKGROUND, BRANCH, FRUIT, LEAF


def test_overlay_tints_each_class_in_a_contrasting_colour_with_outlines():
    rgb = np.zeros((160, 200, 4), np.uint8)   # the legend sits in the top-left corner
    rgb[..., 1] = 140                       # a green scene: leaf and green fruit alike
    cls = np.full((160, 200), BACKGROUND)
    cls[110:130, 110:140] = LEAF
    cls[130:150, 120:140] = FRUIT
    cls[:, 160:164] = BRANCH
    out = Overlay(rgb, cls, title="segmenter: test").astype(int)
    assert out.shape == (160, 200, 3)
    # outlines carry the class colour exactly
    assert tuple(out[130, 130]) == OVERLAY_COLORS[FRUIT]
    assert tuple(out[120, 139]) == OVERLAY_COLORS[LEAF]
    # interiors differ clearly between leaf and fruit although the image is one green
    assert np.abs(out[140, 130] - out[120, 125]).sum() > 150
    # background stays close to the (desaturated) image
    assert np.abs(out[155, 190] - np.array([23, 93, 23])).max() <= 2
