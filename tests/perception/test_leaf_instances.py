"""Leaf instances in dense canopy: touching blades come apart, one curved
blade stays one, and the scores that measure it (issue 57)."""
import numpy as np

from lmap_drake.labels import LEAF
from lmap_drake.perception.config import PerceptionConfig
from lmap_drake.perception.leaf_instances import (LeafInstanceScores, PointLeafInstances,
                                                  SplitAtNecks, SummariseLeafInstances)
from lmap_drake.perception.points import Intrinsics, SplitOversizedLeaves
from lmap_drake.perception.segmentation import InstancesFromComponents

K = Intrinsics(320, 240, 300.0, 300.0, 160.0, 120.0)
V, U = np.mgrid[0:240, 0:320]


def _Blade(cu, cv, half_length, half_width, angle_deg):
    """Pixels of an elliptic blade outline centred at (cu, cv), its long
    axis at ``angle_deg`` from the image's u axis."""
    t = np.deg2rad(angle_deg)
    a = (U - cu) * np.cos(t) + (V - cv) * np.sin(t)
    b = -(U - cu) * np.sin(t) + (V - cv) * np.cos(t)
    return (a / half_length) ** 2 + (b / half_width) ** 2 <= 1.0


def _PlaneDepth(z0, du, dv, cu, cv):
    """Depth (m) of a plane through depth z0 at pixel (cu, cv), rising du and
    dv metres per pixel."""
    return z0 + du * (U - cu) + dv * (V - cv)


def _Instances(mask_ids, depth):
    cls = np.where(mask_ids >= 0, LEAF, 0)
    return np.where(cls == LEAF, InstancesFromComponents(cls, depth), -1)


def _Majority(inst, m):
    ids, counts = np.unique(inst[m], return_counts=True)
    return ids[np.argmax(counts)], counts.max() / m.sum()


def test_touching_blades_at_one_depth_but_different_orientations_come_apart():
    """Two blades touching tip to edge, tilted differently but meeting at
    the same depth (no depth jump to cut at): the outline's neck cuts them,
    each keeps at least 90 % of its pixels in its own instance."""
    a = _Blade(110, 120, 70, 30, 10)
    b = _Blade(215, 110, 50, 28, -35) & ~a
    depth = np.full(U.shape, np.inf)
    depth[a] = _PlaneDepth(0.5, 0.0004, 0.0, 178, 120)[a]       # meets b near u = 178
    depth[b] = _PlaneDepth(0.5, -0.0003, 0.0002, 178, 120)[b]
    ids = np.where(a, 0, np.where(b, 1, -1))
    inst = _Instances(ids, depth)
    (ia, fa), (ib, fb) = _Majority(inst, a), _Majority(inst, b)
    assert ia != ib and fa >= 0.9 and fb >= 0.9
    s = LeafInstanceScores(inst, ids, min_pixels=100)
    assert s["matched"] == 2 and s["merges"] == 0 and s["splits"] == 0
    # without the neck cut (as before) they were one instance: a merge
    before = np.where(ids >= 0, InstancesFromComponents(np.where(ids >= 0, LEAF, 0), depth,
                                                        leaf_neck_ratio=0.0), -1)
    assert LeafInstanceScores(before, ids, min_pixels=100)["merges"] == 1


def test_overlapping_blades_at_different_depths_come_apart():
    """A blade 3 cm in front of another and overlapping it: cut at the depth
    jump, the one behind keeps its visible pixels."""
    back = _Blade(140, 120, 80, 35, 0)
    front = _Blade(200, 130, 60, 30, 25)
    depth = np.full(U.shape, np.inf)
    depth[back] = 0.55
    depth[front] = 0.52
    ids = np.where(front, 1, np.where(back, 0, -1))
    inst = _Instances(ids, depth)
    (i0, f0), (i1, f1) = _Majority(inst, ids == 0), _Majority(inst, ids == 1)
    assert i0 != i1 and f0 >= 0.9 and f1 >= 0.9


def test_one_curved_blade_stays_one_instance():
    """A long blade (about 17 x 4.5 cm at 0.5 m) bent along its length on a
    15 cm radius (2.5 cm of relief) and curled across its width on a 6 cm
    radius, narrowing to its tips, no depth jump: one instance in the image
    and one in the planner's points; so is the default scene's flat
    rectangular leaf with a fruit-shaped notch in its outline."""
    blade = _Blade(160, 120, 50, 14, 0)
    s_long = (U - 160) * 0.5 / K.fx                 # metres along the blade
    s_across = (V - 120) * 0.5 / K.fy
    bend = 0.15 - np.sqrt(np.clip(0.15 ** 2 - s_long ** 2, 0, None))
    curl = 0.06 - np.sqrt(np.clip(0.06 ** 2 - s_across ** 2, 0, None))
    depth = np.where(blade, 0.5 + bend + curl, np.inf)
    ids = np.where(blade, 0, -1)
    inst = _Instances(ids, depth)
    assert set(np.unique(inst[blade])) == {0}
    pts = PointLeafInstances(np.where(blade, LEAF, 0), depth, K, PerceptionConfig())
    got = pts[blade & (pts >= 0)]
    assert len(got) > 0.9 * blade.sum() and len(np.unique(got)) == 1
    rect = (np.abs(U - 160) < 90) & (np.abs(V - 120) < 50)
    rect &= ~(((U - 230) ** 2 + (V - 120) ** 2) < 30 ** 2)      # a fruit in front of it
    parts, n = SplitAtNecks(rect)
    assert n == 1 and set(np.unique(parts[rect])) == {0}


def test_scores_count_matches_merges_and_splits():
    truth = np.full((40, 90), -1)
    truth[:, :30], truth[:, 30:70], truth[:, 70:] = 4, 7, 9
    pred = np.full(truth.shape, -1)
    pred[:, :70] = 0                       # leaves 4 and 7 as one instance: a merge
    pred[:16, 70:], pred[16:, 70:] = 1, 2  # leaf 9 cut in two: a split
    s = LeafInstanceScores(pred, truth, min_pixels=100)
    assert s["best_iou"] == [round(30 / 70, 3), round(40 / 70, 3), 0.6]
    assert (s["leaves"], s["matched"], s["merges"], s["splits"]) == (3, 2, 1, 1)
    assert s["splits_visible_apart"] == 0                # leaf 9 is seen whole
    seen_apart = truth.copy()
    seen_apart[16:18, 70:] = -1                          # a stalk in front of leaf 9
    assert LeafInstanceScores(pred, seen_apart, min_pixels=100)["splits_visible_apart"] == 1
    exact = LeafInstanceScores(truth, truth, min_pixels=100)
    assert (exact["matched"], exact["merges"], exact["splits"]) == (3, 0, 0)
    ignore = np.zeros(truth.shape, bool)
    ignore[:, 70:] = True                  # a neighbouring plant's pixels: left out
    assert LeafInstanceScores(pred, truth, 100, ignore)["leaves"] == 2
    assert LeafInstanceScores(pred, truth, 30 * 40 + 1)["leaves"] == 1   # too small to count
    summary = SummariseLeafInstances([s, exact])
    assert summary["matched_fraction"] == round(5 / 6, 3)
    assert summary["merges_per_view"] == 0.5 and summary["splits_per_view"] == 0.5
    assert summary["mean_best_iou"] == round((0.429 + 0.571 + 0.6 + 3) / 6, 3)


def _Patch(x, y, size_u, size_v, spacing=0.003):
    u, v = np.meshgrid(np.arange(0, size_u, spacing), np.arange(0, size_v, spacing))
    return np.c_[x + u.ravel(), y + v.ravel(), np.zeros(u.size)]


def test_sizes_too_spread_to_count_blades_split_nothing():
    """Leaves seen whole and in part (a dense canopy: the middle half of the
    instances spans more than the 1.5 ratio) give size no meaning: a blade
    three times the median stays whole; told not to check, it is cut."""
    sizes = [(0.03, 0.03), (0.04, 0.04), (0.05, 0.05), (0.07, 0.06), (0.10, 0.07)]
    pts = np.vstack([_Patch(0.2 * k, 0.0, *s) for k, s in enumerate(sizes)])
    inst = np.concatenate([np.full(len(_Patch(0, 0, *s)), k) for k, s in enumerate(sizes)])
    assert np.array_equal(SplitOversizedLeaves(pts, inst), inst)
    assert len(np.unique(SplitOversizedLeaves(pts, inst, check_spread=False))) > 5


def _EllipsePoints(cx, cy, a, b, angle_deg, tilt_deg=0.0, spacing=0.003):
    """Points (m) of an elliptic blade on a ``spacing`` grid, its long axis
    at ``angle_deg`` in the x-y plane, tilted about that axis."""
    u, v = np.meshgrid(np.arange(-a, a, spacing), np.arange(-b, b, spacing))
    keep = (u / a) ** 2 + (v / b) ** 2 <= 1
    u, v = u[keep], v[keep]
    t, s = np.deg2rad(angle_deg), np.deg2rad(tilt_deg)
    w = v * np.sin(s)
    v = v * np.cos(s)
    return np.c_[cx + u * np.cos(t) - v * np.sin(t), cy + u * np.sin(t) + v * np.cos(t), w]


def test_point_blades_touching_in_one_plane_are_split_at_their_neck():
    """Two blades (7 x 3 cm and 5 x 2.5 cm) touching tip to edge in one
    plane, one DBSCAN cluster with no angle between them: cut at the neck,
    each blade keeps 90 % of its points in one instance; noise stays noise.
    One blade curled on a 6 cm radius stays one."""
    from lmap_drake.perception.leaf_instances import SplitLeafNecks
    a = _EllipsePoints(0.0, 0.0, 0.07, 0.03, 0)
    b = _EllipsePoints(0.115, 0.01, 0.05, 0.025, 30)
    b = b[((b[:, 0] / 0.07) ** 2 + (b[:, 1] / 0.03) ** 2) > 1]
    pts = np.vstack([a, b, [[1.0, 1.0, 1.0]]])
    ids = SplitLeafNecks(pts, np.r_[np.zeros(len(a) + len(b), int), -1])
    ia, fa = _Majority(ids[:len(a)], np.ones(len(a), bool))
    ib, fb = _Majority(ids[len(a):-1], np.ones(len(b), bool))
    assert ia != ib and fa >= 0.9 and fb >= 0.9 and ids[-1] == -1
    th, y = np.meshgrid(np.linspace(-0.6, 0.6, 40), np.arange(-0.02, 0.02, 0.003))
    keep = (th / 0.6) ** 2 + (y / 0.02) ** 2 <= 1
    curled = np.c_[0.06 * np.sin(th[keep]), y[keep], 0.06 * (1 - np.cos(th[keep]))]
    assert set(SplitLeafNecks(curled, np.zeros(len(curled), int))) == {0}
