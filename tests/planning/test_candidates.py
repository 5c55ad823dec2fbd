import numpy as np
import pytest
from scipy.spatial import ConvexHull

from lmap_drake.deformation.action import PullDirections
from lmap_drake.planning.candidates import (DirectionsForGrasp, GraspCandidates, LeafPca,
                                            PlanningError)


def _flat_leaf(n=3000, a=0.06, b=0.03, seed=0):
    """Points of an elliptical leaf in the plane y = -0.1 (normal -y toward a
    camera at y = -0.6), centred at (0.5, -0.1, 0.3)."""
    rng = np.random.default_rng(seed)
    r, t = np.sqrt(rng.uniform(0, 1, n)), rng.uniform(0, 2 * np.pi, n)
    return np.c_[0.5 + a * r * np.cos(t), np.full(n, -0.1), 0.3 + b * r * np.sin(t)]


P_WC = np.array([0.5, -0.6, 0.3])


def test_grasps_on_a_flat_leaf():
    leaf = _flat_leaf()
    grasps, dropped = GraspCandidates(leaf, np.zeros((0, 3)), P_WC, num_grasps=15, inset=0.01)
    assert len(grasps) == 15 and not dropped
    frame = LeafPca(leaf, P_WC)
    hull = ConvexHull(frame.To2d(leaf))
    for g in grasps:
        R = g.R_WG
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-9)
        assert np.linalg.det(R) > 0
        np.testing.assert_allclose(R[:, 1], [0, -1, 0], atol=1e-3)  # closing across the leaf
        assert abs(R[:, 2] @ [0, 1, 0]) < 1e-3                     # approach in the plane
        # ~1 cm inside the hull, approach pointing inward
        uv = frame.To2d(g.p_WG[None])[0]
        depth = -np.max(hull.equations[:, :2] @ uv + hull.equations[:, 2])
        assert 0.006 < depth < 0.014
        inward = frame.To2d((g.p_WG + 0.01 * R[:, 2])[None])[0]
        assert np.linalg.norm(inward) < np.linalg.norm(uv)


def test_grasps_near_the_branch_are_dropped():
    leaf = _flat_leaf()
    branch = np.c_[np.full(50, 0.44), np.full(50, -0.1), np.linspace(0.2, 0.4, 50)]
    grasps, dropped = GraspCandidates(leaf, branch, P_WC, 15, 0.01, min_branch_distance=0.03)
    assert len(grasps) + len(dropped) == 15 and dropped
    for g in grasps:
        assert np.linalg.norm(branch - g.p_WG, axis=1).min() >= 0.03


def test_branch_angle_rule():
    p = np.array([0.55, -0.1, 0.3])
    branch = np.array([[0.45, -0.1, 0.3]])  # branch toward -x
    dirs, ids = DirectionsForGrasp(p, branch, 120.0)
    to_branch = np.array([-1.0, 0, 0])
    assert np.all(np.degrees(np.arccos(np.clip(dirs @ to_branch, -1, 1))) < 120.0)
    assert 0 < len(dirs) < 14 and not np.any(np.all(dirs == [1.0, 0, 0], axis=1))
    np.testing.assert_array_equal(PullDirections()[ids], dirs)
    # a tree built once gives the same directions; it is the one queried
    from scipy.spatial import cKDTree
    branch2 = np.array([[0.45, -0.1, 0.3], [0.55, -0.1, 0.45]])
    same, same_ids = DirectionsForGrasp(p, branch2, 120.0, tree=cKDTree(branch2))
    np.testing.assert_array_equal(same_ids, DirectionsForGrasp(p, branch2, 120.0)[1])
    other, _ = DirectionsForGrasp(p, branch2, 120.0, tree=cKDTree(branch2[::-1]))
    assert not np.array_equal(other, same)


def test_too_few_leaf_points():
    with pytest.raises(PlanningError):
        GraspCandidates(np.zeros((3, 3)), np.zeros((0, 3)), P_WC)


def test_narrow_opening_follows_the_leafs_local_thickness():
    """The retry opening clears the observed leaf (its local spread along the
    closing direction, noise included) by the collision margin + 3 mm on
    each pad; it is never wider than the configured opening nor below 1.5 cm."""
    from types import SimpleNamespace

    from lmap_drake.planning.approach import NarrowOpening
    from lmap_drake.planning.config import PlannerConfig
    rng = np.random.default_rng(0)
    leaf = np.c_[rng.uniform(-0.05, 0.05, (4000, 2)), np.zeros(4000)]   # the plane z = 0
    grasp = SimpleNamespace(p_WG=np.zeros(3), R_WG=np.eye(3)[:, [0, 2, 1]])  # closes along z
    cfg = PlannerConfig()
    thin = NarrowOpening(leaf, grasp, cfg)
    assert thin == pytest.approx(max(0.015, 2 * (cfg.collision_margin + 0.003)))
    noisy = leaf + np.c_[np.zeros((4000, 2)), rng.normal(0, 0.004, 4000)]
    wide = NarrowOpening(noisy, grasp, cfg)
    assert wide == pytest.approx(2 * (1.96 * 0.004 + cfg.collision_margin + 0.003), rel=0.1)
    very_noisy = leaf + np.c_[np.zeros((4000, 2)), rng.normal(0, 0.02, 4000)]
    assert NarrowOpening(very_noisy, grasp, cfg) == cfg.pregrasp_opening


def test_grasp_alternatives_keep_the_pads_across_the_leaf():
    from lmap_drake.planning.candidates import (APPROACH_TILTS_DEG, AlternativeLabels,
                                                GraspAlternatives)
    # pads close along y = the leaf normal (W y); approach z along W +x
    R = np.column_stack([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
    alts = GraspAlternatives(R)
    assert len(alts) == 2 * len(APPROACH_TILTS_DEG) - 1 == len(AlternativeLabels())
    assert max(APPROACH_TILTS_DEG) < 90.0
    for A, (tilt, turned) in zip(alts, AlternativeLabels()):
        assert np.allclose(A.T @ A, np.eye(3)) and np.isclose(np.linalg.det(A), 1.0)
        assert np.isclose(abs(A[:, 1] @ R[:, 1]), 1.0)         # closing axis: the leaf normal
        assert abs(A[:, 2] @ R[:, 1]) < 1e-12                  # approach in the blade plane
        # tilted by the labelled angle, still toward the leaf (not along its edge)
        assert np.isclose(A[:, 2] @ R[:, 2], np.cos(np.deg2rad(tilt)))
        assert np.isclose(A[:, 1] @ R[:, 1], -1.0 if turned else 1.0)
        assert not np.allclose(A, R)
    # the 180-degree turn about the approach axis is among them
    assert any(np.allclose(A, R @ np.diag([-1.0, -1.0, 1.0])) for A in alts)


def test_the_pull_cap_grows_with_the_lever_but_not_past_the_pulls_it_was_measured_on():
    """``MaxPullDistance``: 3 cm at a 10 cm lever, scaled by the lever
    squared, never past ``MEASURED_PULL_MAX``; the extra pull candidate
    is the lever's limit where it lies under that ceiling, and none is
    added where the ceiling holds instead (no 6 cm pull at any lever)."""
    from lmap_drake.planning.candidates import PullDistances
    from lmap_drake.planning.config import PlannerConfig
    from lmap_drake.planning.energy import MEASURED_PULL_MAX, MaxPullDistance
    cfg = PlannerConfig()
    hinge = np.zeros(3)
    grasp = lambda L: np.array([0.0, 0.0, -L])
    assert MaxPullDistance(cfg, grasp(0.10), hinge) == pytest.approx(0.03)
    assert MaxPullDistance(cfg, grasp(0.12), hinge) == pytest.approx(0.03 * 1.44)
    assert MaxPullDistance(cfg, grasp(0.14), hinge) == MEASURED_PULL_MAX == 0.045
    assert MaxPullDistance(cfg, grasp(0.30), hinge) == MEASURED_PULL_MAX
    assert PullDistances(cfg, grasp(0.105), hinge) == [0.02, 0.033, 0.04, 0.06, 0.08]
    assert PullDistances(cfg, grasp(0.14), hinge) == [0.02, 0.04, 0.06, 0.08]
    assert MaxPullDistance(cfg, grasp(0.14), None) == pytest.approx(0.03)   # no hinge: unscaled
