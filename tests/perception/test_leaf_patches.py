import numpy as np

from lmap_drake.labels import FRUIT, LEAF
from lmap_drake.perception.leaf_patches import (LEAF_PATCH_FLAG, FruitPatchesInLeaves,
                                                VetoLeafPatches)


def test_a_leaf_patch_is_found_a_fruit_past_or_before_a_leaf_is_not():
    """A patch of a leaf called fruit (bordered by the leaf, at its depth) is
    found; a fruit seen through a gap between leaves (their rims in front)
    and a fruit hanging in front of a leaf (its silhouette in front) are
    not, nor a fruit whose border is mostly background."""
    rng = np.random.default_rng(1)
    H, W = 60, 120
    v, u = np.mgrid[0:H, 0:W]
    noise = rng.normal(0, 0.0015, (H, W))
    # a tilted leaf plane across the image, 0.50-0.53 m
    leaf_d = 0.50 + 0.03 * u / W
    cls = np.full((H, W), LEAF)
    depth = leaf_d.copy()
    # 1: a tinted patch of the leaf, called fruit (same surface)
    patch = ((u - 20) ** 2 + (v - 30) ** 2) < 8 ** 2
    cls[patch] = FRUIT
    # 2: a fruit seen through a hole in the leaf, 4 cm behind it
    r2 = ((u - 60) ** 2 + (v - 30) ** 2) / 9.0 ** 2
    behind = r2 < 1
    cls[behind] = FRUIT
    depth = np.where(behind, leaf_d + 0.04 - 0.02 * np.sqrt(np.clip(1 - r2, 0, 1)), depth)
    # 3: a fruit hanging 3 cm in front of the leaf
    r3 = ((u - 100) ** 2 + (v - 30) ** 2) / 10.0 ** 2
    front = r3 < 1
    cls[front] = FRUIT
    depth = np.where(front, leaf_d - 0.03 - 0.02 * np.sqrt(np.clip(1 - r3, 0, 1)), depth)
    depth = depth + noise
    out = FruitPatchesInLeaves(cls, depth)
    assert out[patch].all()
    assert not out[behind].any() and not out[front].any()
    assert not out[cls != FRUIT].any()
    # the camera drops the returns on one side of the patch: the continuity
    # is judged on the border pairs it measured
    dropped = depth.copy()
    dropped[(u > 16) & (u < 32) & (v > 18) & (v < 42) & ~patch] = np.inf
    assert FruitPatchesInLeaves(cls, dropped)[patch].all()
    # the patch alone on background (no leaf around it) is left alone
    alone = np.where(patch, FRUIT, np.where(u < 6, LEAF, 0))
    assert not FruitPatchesInLeaves(alone, depth).any()
    # the patch's instance is vetoed as a target (confidence 0, flagged),
    # its pixels stay fruit (an obstacle); the two fruits keep theirs
    inst = np.full((H, W), -1)
    inst[patch], inst[behind], inst[front] = 2, 0, 1
    conf = {(FRUIT, 0): 0.95, (FRUIT, 1): 0.97, (FRUIT, 2): 0.9}
    flags = VetoLeafPatches(conf, cls, inst, out)
    assert conf == {(FRUIT, 0): 0.95, (FRUIT, 1): 0.97, (FRUIT, 2): 0.0}
    assert flags == [f"{LEAF_PATCH_FLAG}:2"]
    assert (cls[patch] == FRUIT).all()
