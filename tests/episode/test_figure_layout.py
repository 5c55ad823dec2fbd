"""Episode pictures on dense plants (``episode/figure_layout.py`` and the
focus of ``figures.Overlay``): labels placed apart and inside the image,
instance outlines between touching leaves, the ground-truth focus (target
fruits, the leaves hiding them) from a label image, and an overlay where
the focus stands out and the other leaves fade."""
import numpy as np

from lmap_drake.episode.figure_layout import (FOCUS_FRUIT, GroundTruthFocus, InstanceEdges,
                                              MaskAnchor, PlaceLabels, TextBox)
from lmap_drake.episode.figures import OVERLAY_COLORS, Overlay
from lmap_drake.labels import BACKGROUND, FRUIT, LEAF, EncodeLabel


def _boxes(corners, sizes):
    return [(u, v, u + w, v + h) for (u, v), (w, h) in zip(corners, sizes)]


def test_labels_of_a_crowded_spot_do_not_overlap_and_stay_in_the_image():
    anchors = [(300 + 3 * k, 200 + 2 * k) for k in range(12)] + [(635, 2), (2, 478)]
    sizes = [TextBox(f"leaf {k} (hides fruit 0)") for k in range(14)]
    legend = [(4, 4, 200, 70)]
    boxes = _boxes(PlaceLabels(anchors, sizes, (480, 640), legend), sizes)
    for i, a in enumerate(boxes):
        assert 0 <= a[0] and a[2] <= 640 and 0 <= a[1] and a[3] <= 480
        for b in boxes[i + 1:] + legend:
            assert min(a[2], b[2]) <= max(a[0], b[0]) or min(a[3], b[3]) <= max(a[1], b[1])


def test_instance_edges_separate_touching_leaves():
    cls = np.full((20, 20), BACKGROUND)
    cls[5:15, 2:18] = LEAF
    inst = np.full((20, 20), -1)
    inst[5:15, 2:10], inst[5:15, 10:18] = 0, 1
    e = InstanceEdges(cls, inst)
    assert e[10, 9] and e[10, 10]                 # where the two leaves meet
    assert not e[10, 5] and not e[10, 14]         # inside each
    assert e[5, 5] and not e[0, 0]                # the outline, not the background


def test_ground_truth_focus_is_the_targets_and_their_occluders_in_view():
    lab = np.zeros((40, 40), np.int32)
    lab[5:15, 5:15] = EncodeLabel(FRUIT, 1)
    lab[12:30, 0:20] = EncodeLabel(LEAF, 4)
    lab[25:35, 25:35] = EncodeLabel(LEAF, 7)
    focus = GroundTruthFocus(lab, {1: [4, 9, 7], 0: [4]})   # leaf 9 and fruit 0 not in view
    assert [f["text"] for f in focus] == ["target fruit 1", "leaf 4 (hides fruit 1)",
                                          "leaf 7 (hides fruit 1)"]
    assert focus[0]["color"] == FOCUS_FRUIT and focus[1]["color"] != focus[2]["color"]
    assert focus[1]["mask"].sum() == (lab == EncodeLabel(LEAF, 4)).sum()
    u, v = MaskAnchor(focus[2]["mask"])
    assert focus[2]["mask"][int(v), int(u)]


def test_overlay_focus_stands_out_and_other_leaves_fade():
    rgb = np.zeros((160, 200, 4), np.uint8)
    rgb[..., 1] = 140
    cls = np.full((160, 200), BACKGROUND)
    inst = np.full((160, 200), -1)
    cls[100:150, 20:80], inst[100:150, 20:80] = LEAF, 0        # the occluder
    cls[100:150, 120:180], inst[100:150, 120:180] = LEAF, 1    # another leaf
    mask = cls.astype(bool) & (inst == 0)
    focus = [{"mask": mask, "text": "leaf 0 (hides fruit 0)", "color": (255, 140, 0),
              "kind": "leaf"}]
    plain = Overlay(rgb, cls, instance_map=inst).astype(int)
    out = Overlay(rgb, cls, instance_map=inst, focus=focus).astype(int)
    assert tuple(out[149, 50]) == (255, 140, 0)                 # the focus outline
    tint = lambda img: np.abs(img[142, 165] - np.array([23, 93, 23])).sum()
    assert tint(out) < 0.6 * tint(plain)                        # the other leaf fades
    # the focus label: an orange-framed box somewhere outside the legend
    framed = np.all(out == (255, 140, 0), axis=2)
    framed[100:150, 20:80] = False
    assert framed.sum() > 40
    assert tuple(plain[149, 50]) == OVERLAY_COLORS[LEAF]
