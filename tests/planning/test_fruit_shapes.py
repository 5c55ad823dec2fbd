"""Plans safe against the set of plausible fruit shapes (``planner.fruit_shapes``,
``planner.visibility_shapes``): the leaf-fruit and robot-fruit checks keep
clear of the union of the estimate and its kept shape hypotheses, the
visibility is the mean over them, and the plan says which were used.
Functional: no Diagram."""
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from lmap_drake.deformation.action import Action
from lmap_drake.deformation.graph import FREE
from lmap_drake.planning.collision import RobotCollisionReason
from lmap_drake.planning.config import PlannerConfig, PlannerConfigError, ValidatePlannerConfig
from lmap_drake.planning.context import PlanningContext, VisibilitySurfaces
from lmap_drake.planning.result import Candidate, CandidateSet
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.planning.selection import SelectFromPredictions
from lmap_drake.planning.visibility import VisibilityModel
from lmap_drake.station.config import RobotConfig
from lmap_drake.types import FruitEstimate, SceneEstimate, SemanticScene, ShapeHypotheses

# camera at y = -0.6 looking along +y (as in test_visibility)
X_WC = np.array([[1, 0, 0, 0.5], [0, 0, 1, -0.6], [0, -1, 0, 0.3], [0, 0, 0, 1.0]])
C = np.array([0.5, 0.0, 0.3])
R_SMALL, R_BIG = 0.03, 0.045
# the larger hypothesis: the same front (the seen part), its back pushed away
# from the camera, so it reaches 1.5 cm above the estimate's top
C_BIG = C + [0.0, 0.015, 0.0]


def _Sphere(c, r):
    return lambda p: np.linalg.norm(np.asarray(p, float) - c, axis=1) - r  # noqa: E731


def _Fruit(with_hypotheses: bool = True) -> FruitEstimate:
    small = trimesh.creation.icosphere(3, radius=R_SMALL).apply_translation(C)
    big = trimesh.creation.icosphere(3, radius=R_BIG).apply_translation(C_BIG)
    est = FruitEstimate(np.asarray(small.vertices), np.asarray(small.faces), np.eye(4),
                        np.zeros(2), C, np.array([0, 0, 1.0]), sdf_W=_Sphere(C, R_SMALL))
    if with_hypotheses:
        n = 2
        vols = np.array([4 / 3 * np.pi * R_SMALL ** 3, 4 / 3 * np.pi * R_BIG ** 3]) * 1e6
        est.hypotheses = ShapeHypotheses(
            vertices_W=[est.vertices_W, np.asarray(big.vertices)],
            faces=[est.faces, np.asarray(big.faces)],
            X_WO=np.tile(np.eye(4), (n, 1, 1)), latents=np.zeros((n, 2)), volume_cm3=vols,
            center_W=np.array([C, C_BIG]), axis_W=np.array([[0, 0, 1.0]] * n),
            residual_m=np.zeros(n), inlier_fraction=np.ones(n), inside_fraction=np.zeros(n),
            num_fitted=4, volume_interval_cm3=np.array([vols.min(), vols.max()]),
            center_interval_W=np.array([C, C_BIG]), axis_spread_deg=0.0)
    return est


def _Plate(center, half=0.015, step=0.003):
    g = np.arange(-half, half + 1e-9, step)
    u, v = np.meshgrid(g, g)
    return np.c_[center[0] + u.ravel(), center[1] + v.ravel(), np.full(u.size, center[2])]


# a leaf lying 5 cm above the estimate's top, predicted to come down to 8 mm
# above it: clear of the estimate, inside the larger hypothesis
LEAF_REST = _Plate(C_BIG + [0, 0, 0.08])
LEAF_MOVED = _Plate(C_BIG + [0, 0, R_SMALL + 0.008])


def _Context(fruit_shapes: str, fruit=None) -> PlanningContext:
    sem = SemanticScene(leaf_points_W=LEAF_REST, leaf_instance=np.zeros(len(LEAF_REST), int),
                        branch_points_W=np.zeros((0, 3)), X_WC=X_WC)
    scene = SceneEstimate(semantic=sem, fruit=fruit or _Fruit())
    robot = RobotModel(RobotConfig().X_WB.GetDeterministicValue())
    return PlanningContext(scene, X_WC, robot, np.array(RobotConfig().initial_q),
                           fruit_shapes=fruit_shapes)


def _Plan(fruit_shapes: str, visibility_shapes: str = "expected"):
    """The planner's selection on one candidate whose predicted leaf ends
    ``LEAF_MOVED`` (the prediction: a stand-in with the fields the selection
    reads from a ``PredictDeformations`` result)."""
    # (no petiole attachment here: the pull's lever cap is off)
    cfg = PlannerConfig(fruit_shapes=fruit_shapes, visibility_shapes=visibility_shapes,
                        max_pull_distance=0.0)
    ctx = _Context(fruit_shapes)
    vis = VisibilityModel(X_WC, VisibilitySurfaces(ctx.scene.fruit, visibility_shapes))
    cset = CandidateSet("ok", ctx.scene, visibility=vis,
                        seen_init_mask=vis.Seen(np.vstack([ctx.leaf_W, ctx.occluders_W])))
    c = Candidate(Action(LEAF_REST.mean(0), np.eye(3), np.array([0.0, 0.0, -0.042]),
                         grasp_id=0, direction_id=0), 1)
    c.q_pulled = np.array(RobotConfig().initial_q)
    cset.candidates = [c]
    pred = SimpleNamespace(energy=1e-9, node_kind=np.full(20, FREE), leaf_points_W=LEAF_MOVED)
    return SelectFromPredictions(ctx, cset, [pred], cfg)


def test_a_leaf_pressed_into_a_larger_hypothesis_is_rejected_under_union_only():
    """The predicted leaf ends 8 mm above the estimate (clear of its 5 mm
    margin) but inside the larger plausible shape: under ``union`` the
    action is rejected for leaf-fruit and the plan has none; under
    ``estimate`` it is chosen."""
    assert _Sphere(C, R_SMALL)(LEAF_MOVED).min() > PlannerConfig().collision_margin
    assert _Sphere(C_BIG, R_BIG)(LEAF_MOVED).max() < 0
    est = _Plan("estimate")
    assert est.status == "ok" and est.chosen is not None and est.chosen.reason == ""
    union = _Plan("union")
    assert union.status == "no_feasible_action" and union.chosen is None
    assert union.candidates[0].reason.startswith("leaf-fruit"), union.candidates[0].reason
    # the plan says what its checks used: the estimate and one more shape
    fs = union.fruit_shapes
    assert fs["checks"] == "union" and fs["num_checked_shapes"] == 2
    assert fs["num_hypotheses_kept"] == 2 and fs["num_visibility_shapes"] == 2
    assert fs["volume_interval_cm3"][0] == pytest.approx(113.1, abs=0.1)
    assert est.fruit_shapes["checks"] == "estimate" and est.fruit_shapes["num_checked_shapes"] == 1


def test_the_robot_keeps_clear_of_every_plausible_shape_under_union():
    """Robot samples 8 mm above the estimate, inside the larger hypothesis:
    the robot-fruit check passes on the estimate, fails on the union; far
    away both pass (the union is evaluated only near its box); without
    hypotheses the two keys agree."""
    union, est = _Context("union"), _Context("estimate")
    pts = LEAF_MOVED
    margin = PlannerConfig().collision_margin
    assert RobotCollisionReason(pts, est.fruit_sdf, None, margin, est.fruit_box) == ""
    assert RobotCollisionReason(pts, union.fruit_sdf, None, margin,
                                union.fruit_box).startswith("robot-fruit")
    far = pts + [0.3, 0, 0]
    assert RobotCollisionReason(far, union.fruit_sdf, None, margin, union.fruit_box) == ""
    # the union's box holds the larger hypothesis
    assert union.fruit_box[1][2] > est.fruit_box[1][2] + 0.01
    bare = _Context("union", _Fruit(with_hypotheses=False))
    assert bare.fruit_sdf is bare.scene.fruit.sdf_W


def test_expected_visibility_is_the_mean_of_the_shapes_visible_fractions():
    """Over two shapes the counts are the mean of each one's visible
    fraction, in units of the estimate's voxels: the whole of both seen
    counts as the estimate's count; an occluder hiding the estimate but
    not the larger shape's rim counts as about half the mean of the two
    models computed on their own."""
    fruit = _Fruit()
    one = VisibilityModel(X_WC, VisibilitySurfaces(fruit, "estimate"))
    assert one.num_shapes == 1 and one.Count(one.max_seen) == int(one.max_seen.sum())
    both = VisibilityModel(X_WC, VisibilitySurfaces(fruit, "expected"))
    assert both.num_shapes == 2
    # (one grid for both shapes, a little coarser or finer than the estimate's own)
    assert both.Count(both.max_seen) == np.count_nonzero(both.max_seen & (both.group == 0))
    assert both.Count(both.max_seen) == pytest.approx(one.Count(one.max_seen), rel=0.03)
    big = VisibilityModel(X_WC, VisibilitySurfaces(fruit, "expected")[1])
    # a disc in front hiding the estimate, not the larger shape's rim
    g = np.arange(-0.03, 0.03 + 1e-9, 0.002)
    u, v = np.meshgrid(g, g)
    disc = np.c_[C[0] + u.ravel(), np.full(u.size, -0.1), C[2] + v.ravel()]
    disc = disc[np.hypot(u.ravel(), v.ravel()) < 0.029]
    frac = [m.Count(m.Seen(disc)) / m.Count(m.max_seen) for m in (one, big)]
    assert frac[0] < 0.05 < 0.2 < frac[1]
    got = both.Count(both.Seen(disc)) / both.Count(both.max_seen)
    assert got == pytest.approx(np.mean(frac), abs=0.03)
    # the expected count ranks the actions as the visible fractions do
    assert both.Count(both.Seen(disc[: len(disc) // 2])) > both.Count(both.Seen(disc))


@pytest.mark.parametrize("key", ["fruit_shapes", "visibility_shapes"])
def test_a_bad_shapes_key_names_itself(key):
    with pytest.raises(PlannerConfigError) as err:
        ValidatePlannerConfig(PlannerConfig(**{key: "both"}))
    assert err.value.key == f"planner.{key}" and "'both' unknown" in err.value.detail


def test_mesh_set_sdf_is_the_union_outside_and_negative_inside():
    """``MeshSetSdf`` (several hypotheses for the price of one distance
    query): outside every mesh the min of their signed distances; inside
    any, negative and never deeper than the true union's value."""
    from lmap_drake.planning.collision import MeshSdf, MeshSetSdf
    a = trimesh.creation.icosphere(3, radius=0.03).apply_translation(C)
    b = trimesh.creation.icosphere(3, radius=0.04).apply_translation(C + [0.03, 0, 0])
    each = [MeshSdf(m.vertices, m.faces) for m in (a, b)]
    union = MeshSetSdf([(m.vertices, m.faces) for m in (a, b)])
    p = np.random.default_rng(3).uniform(C - 0.05, C + [0.08, 0.05, 0.05], (4000, 3))
    exact = np.min([s(p) for s in each], axis=0)
    got = union(p)
    out = exact > 0
    assert out.sum() > 300 and (~out).sum() > 300
    assert np.allclose(got[out], exact[out], atol=1e-6)
    assert np.all(got[~out] < 0) and np.all(got[~out] >= exact[~out] - 1e-6)
    assert len(union(np.zeros((0, 3)))) == 0


def test_a_margin_beyond_the_exact_range_of_the_union_is_refused():
    """Under ``union`` the fruit distances are exact up to 3 cm
    (``FRUIT_SET_PAD``): a larger margin is refused naming its key; the
    estimate alone keeps any margin."""
    with pytest.raises(PlannerConfigError) as err:
        ValidatePlannerConfig(PlannerConfig(robot_fruit_margin=0.04, fruit_shapes="union"))
    assert err.value.key == "planner.robot_fruit_margin" and "'union'" in err.value.detail
    ValidatePlannerConfig(PlannerConfig(robot_fruit_margin=0.04, fruit_shapes="estimate"))


def test_an_approach_checked_for_its_verdict_only_passes_or_fails_as_the_full_one():
    """``GraspApproach(..., verdict_only=True)`` (another orientation of a
    grasp, whose reason is not kept): the same approach (joints) where the
    full check passes, a failure with the same reason up to its
    parenthesis where it fails, under ``union`` (hypothesis meshes)."""
    from lmap_drake.planning.approach import GraspApproach
    from lmap_drake.planning.candidates import Grasp
    ctx = _Context("union")
    cfg = PlannerConfig()
    R = np.c_[[-1.0, 0, 0], [0, 0, 1.0], [0, 1.0, 0]]       # approach along +y
    outcomes = []
    for k, dp in enumerate([[0, -0.07, 0.05], [0, -0.05, 0.0], [0, -0.035, 0.0],
                            [0.02, -0.04, 0.02], [0, -0.10, 0.08]]):
        g = Grasp(C + np.asarray(dp), R, k)
        full, why = GraspApproach(ctx, g, cfg)
        fast, why_fast = GraspApproach(ctx, g, cfg, verdict_only=True)
        assert (full is None) == (fast is None)
        assert why.split(" (")[0] == why_fast.split(" (")[0]
        if full is not None:
            for seg in ("to_ready", "to_pregrasp", "to_grasp"):
                assert all(np.array_equal(a, b) for a, b in zip(getattr(full, seg),
                                                                getattr(fast, seg)))
        outcomes.append(why.split(" (")[0])
    assert "" in outcomes and any(o.startswith("robot-fruit") for o in outcomes), outcomes


def test_a_grasp_surely_blocked_has_no_approach():
    """``GraspSurelyBlocked`` (an orientation skipped without IK) says so
    only of grasps whose approach fails; grasps with the fingers in the
    fruit's hypotheses are found, and approaches that pass are not."""
    from lmap_drake.planning.approach import GraspApproach, GraspSurelyBlocked
    from lmap_drake.planning.candidates import Grasp
    ctx = _Context("union")
    cfg = PlannerConfig()
    R = np.c_[[-1.0, 0, 0], [0, 0, 1.0], [0, 1.0, 0]]       # approach along +y
    seen = set()
    for k, dp in enumerate([[0, -0.07, 0.05], [0, -0.05, 0.0], [0, -0.035, 0.0],
                            [0.02, -0.04, 0.02], [0, -0.10, 0.08], [0, -0.02, 0.0],
                            [0, 0.0, 0.0], [0.01, -0.01, 0.01]]):
        g = Grasp(C + np.asarray(dp), R, k)
        blocked = GraspSurelyBlocked(ctx, g, cfg)
        approach, why = GraspApproach(ctx, g, cfg, verdict_only=True)
        if blocked:
            assert approach is None, dp
        seen.add((blocked, approach is None))
    assert (True, True) in seen and (False, False) in seen, seen
