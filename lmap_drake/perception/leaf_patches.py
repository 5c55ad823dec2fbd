"""Fruit regions that lie in a leaf's surface: a segmenter's tinted or
shaded leaf patch called fruit (a phantom the planner would target). Image
arrays HxW; depths in metres; class ids of ``lmap_drake.labels``."""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from lmap_drake.labels import FRUIT, LEAF
from lmap_drake.perception.points import Neighbour, ValidDepthMask

# A fruit region is a patch of leaf when at least ``LEAF_PATCH_BORDER`` of
# its outline borders leaf pixels and at least ``LEAF_PATCH_CONTINUITY`` of
# those border pairs continue the leaf's surface (depth within
# ``LEAF_PATCH_STEP`` m). A pepper hangs apart from the leaves: where a
# leaf hides it the leaf's rim lies in front of it, where it hides a leaf
# its silhouette lies in front; either way the border is a depth step.
# Chosen on segnet's fruit regions of 30 greenhouse stills (the suite and
# seeds 6464, 7575; numbers: docs/explanation/dense-canopy.md).
LEAF_PATCH_BORDER = 0.5
LEAF_PATCH_CONTINUITY = 0.75
LEAF_PATCH_STEP = 0.006


def FruitPatchesInLeaves(cls: np.ndarray, depth: np.ndarray,
                         border: float = LEAF_PATCH_BORDER,
                         continuity: float = LEAF_PATCH_CONTINUITY,
                         step: float = LEAF_PATCH_STEP) -> np.ndarray:
    """HxW bool: the pixels of every 8-connected fruit region of ``cls``
    that lies in a leaf's surface (mostly bordered by leaf pixels whose
    depth, ``depth`` HxW m, continues its own: see ``LEAF_PATCH_BORDER``).
    A segmenter's shaded or tinted leaf patch called fruit; never a fruit
    seen past a leaf's rim or in front of a leaf."""
    out = np.zeros(cls.shape, bool)
    fruit = cls == FRUIT
    if not fruit.any() or not (cls == LEAF).any():
        return out
    d = np.where(ValidDepthMask(depth), np.asarray(depth, np.float64), np.nan)
    lab, n = ndimage.label(fruit, structure=np.ones((3, 3)))
    edge = np.zeros(n + 1)      # outline pairs per region (4-neighbours not in it)
    on_leaf = np.zeros(n + 1)   # of those, with a leaf pixel
    known = np.zeros(n + 1)     # of those, both depths valid
    smooth = np.zeros(n + 1)    # of those, the leaf continuing the depth
    leaf = cls == LEAF
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        nb_fruit, nb_leaf = Neighbour(fruit, dy, dx, False), Neighbour(leaf, dy, dx, False)
        nb_d = Neighbour(d, dy, dx, np.nan)
        at = fruit & ~nb_fruit
        at[:, -1 if dx > 0 else 0] &= dx == 0     # no neighbour past the image's edge
        at[-1 if dy > 0 else 0, :] &= dy == 0
        edge += np.bincount(lab[at], minlength=n + 1)
        on_leaf += np.bincount(lab[at & nb_leaf], minlength=n + 1)
        measured = at & nb_leaf & np.isfinite(nb_d) & np.isfinite(d)
        known += np.bincount(lab[measured], minlength=n + 1)
        with np.errstate(invalid="ignore"):
            smooth += np.bincount(lab[measured & (np.abs(nb_d - d) < step)], minlength=n + 1)
    # the continuity over the border pairs with both depths (the camera
    # drops returns along edges; a depth step is judged where it is seen)
    patch = ((on_leaf >= border * edge) & (known > 0)
             & (smooth >= continuity * np.maximum(known, 1)))
    patch[0] = False
    return patch[lab]


# The scene flag of a fruit instance vetoed as a leaf patch (``LEAF_PATCH_FLAG:i``).
LEAF_PATCH_FLAG = "fruit_in_leaf_surface"


def VetoLeafPatches(confidence: dict, cls: np.ndarray, inst: np.ndarray,
                    patch: np.ndarray) -> list[str]:
    """Sets to 0 the confidence (``confidence``, {(class, instance):
    score}, changed in place) of every fruit instance of ``inst`` whose
    pixels lie mostly in ``patch`` (``FruitPatchesInLeaves``), and returns a
    flag per instance. The pixels stay fruit: such an instance is no target
    (``planner.min_fruit_confidence``) but stays an obstacle, since a real
    fruit taken for a patch must still be kept clear of."""
    flags = []
    fruit = (cls == FRUIT) & (inst >= 0)
    if not patch.any() or not fruit.any():
        return flags
    n = int(inst[fruit].max()) + 1
    total = np.bincount(inst[fruit], minlength=n)
    inside = np.bincount(inst[fruit & patch], minlength=n)
    for i in np.flatnonzero(inside * 2 > total):
        confidence[(FRUIT, int(i))] = 0.0
        flags.append(f"{LEAF_PATCH_FLAG}:{int(i)}")
    return flags
