"""Reaching through foliage: the robot may push a leaf it does not hold by
at most ``planner.max_brush_displacement`` (how far the leaf must move
along its normal to clear the robot by the collision margin), less near a
stem; the grasped leaf, leaf points near a fruit, the fruit and the branch
keep today's rules."""
from types import SimpleNamespace

import numpy as np
import pytest

from lmap_drake.deformation.action import Action
from lmap_drake.planning.approach import IkAndRobotChecks
from lmap_drake.planning.config import PlannerConfig, ValidatePlannerConfig
from lmap_drake.planning.robot_checks import (BRUSH_FRUIT_CLEARANCE, BRUSH_MAX_FORCE,
                                              BeamPetioleForce, BrushAllowance,
                                              BrushPetioleForce)
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.errors import ConfigError
from lmap_drake.station.config import RobotConfig

# The TCP 45 cm in front of the base, 30 cm up, approaching from above with
# the pads closing along y: the pads reach 1.9 cm below the TCP and 1.1 cm
# either side of it along x (``RobotModel``'s 2F-85 pads).
R_WG = np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]])
P_WG = RobotConfig().X_WB.GetDeterministicValue().translation() + [0.45, 0.0, 0.30]
PAD_EDGE_X = 0.011     # the pads' side faces, m from the TCP along x
NONE = np.zeros((0, 3))


@pytest.fixture(scope="module")
def robot():
    return RobotModel(RobotConfig().X_WB.GetDeterministicValue())


def _Ctx(robot, leaf=NONE, other=NONE, fruit_sdf=None, branch=None, p_WC=None):
    """A planning context with the given leaf points (W): a branch 25 cm
    to the side unless ``branch`` is given; no camera unless ``p_WC``."""
    return SimpleNamespace(robot=robot, q_current=np.array(RobotConfig().initial_q), p_WC=p_WC,
                           leaf_W=leaf, other_leaves_W=other, fruit_sdf=fruit_sdf,
                           branch_distance=None, fruit_box=None, branch_box=None,
                           branch_all_W=(np.array([P_WG + [0, 0.25, 0]]) if branch is None
                                         else branch))


def _Sheet(z: float) -> np.ndarray:
    """A level leaf ``z`` (m) above the TCP (below it: the pads poke
    through), 4 x 6 cm around the grasp, points every 2 mm."""
    x, y = np.meshgrid(np.arange(-0.02, 0.0201, 0.002), np.arange(-0.03, 0.0301, 0.002))
    return P_WG + np.c_[x.ravel(), y.ravel(), np.full(x.size, z)]


def _Plan(robot, ctx, **cfg):
    grasp = SimpleNamespace(p_WG=P_WG, R_WG=R_WG, grasp_id=0)
    pull = Action(P_WG, R_WG, dp_W=np.array([0.0, 0.0, 0.02]), grasp_id=0, direction_id=0)
    (c,) = IkAndRobotChecks(ctx, grasp, PlannerConfig(**cfg), [pull])
    return c


def test_the_robots_signed_distance_is_drakes(robot):
    """The analytic distance to the boxes, capsules and cylinders equals
    SceneGraph's own point query."""
    q = np.array(RobotConfig().initial_q)
    S = robot.SurfacePointsByBody(q, 0.02)
    rng = np.random.default_rng(0)
    P = np.vstack(list(S))
    pts = P[rng.choice(len(P), 200)] + rng.normal(0, 0.02, (200, 3))
    got = S.SignedDistance(pts, 0.05)
    robot.SetQ(q, 0.02)
    query = robot.scene_graph.get_query_output_port().Eval(
        robot.scene_graph.GetMyContextFromRoot(robot._diagram_context))
    ref = np.array([min([r.distance for r in query.ComputeSignedDistanceToPoint(p, 0.05)],
                        default=np.inf) for p in pts])
    close = np.isfinite(ref) & (ref < 0.05)
    assert close.sum() > 150 and (ref[close] < 0).sum() > 50
    np.testing.assert_allclose(got[close], ref[close], atol=1e-9)
    from scipy.spatial import cKDTree
    with_tree = S.SignedDistance(pts, 0.05, cKDTree(pts))
    np.testing.assert_allclose(with_tree[close], ref[close], atol=1e-9)
    # the tree's batched ball query finds exactly the points the boxes do
    below = got < 0.05
    np.testing.assert_array_equal(with_tree < 0.05, below)
    np.testing.assert_array_equal(with_tree[below], got[below])


def test_the_brush_bound_is_well_below_the_plant_hazard_limit():
    """At most 5 N predicted on the petiole (a third of the 15 N limit)
    wherever the push is: 1 cm from 10.2 cm from the stem on, less nearer.
    The prediction has the beam's form with the FEM leaf's k, 5.2 N m,
    about five times the beam's own (1.08 N m, E 10 MPa, 6 x 2 mm)."""
    bound = PlannerConfig().max_brush_displacement
    assert bound == 0.01 and BRUSH_MAX_FORCE == 5.0 and BRUSH_FRUIT_CLEARANCE == 0.03
    assert BeamPetioleForce(0.01, 0.1) == pytest.approx(1.08, abs=1e-3)
    assert BrushPetioleForce(0.01, 0.1) == pytest.approx(5.2)
    levers = np.linspace(0.005, 0.3, 120)
    allowed = BrushAllowance(levers, bound)
    assert np.all(allowed <= bound) and np.all(np.diff(allowed) >= 0)
    assert np.all(allowed[levers >= 0.102] == bound) and np.all(allowed[levers < 0.101] < bound)
    loads = BrushPetioleForce(allowed, levers)
    assert loads.max() == pytest.approx(BRUSH_MAX_FORCE) and loads.max() <= 15.0 / 3 + 1e-9
    assert BrushAllowance(0.06, bound) < 0.005      # near a stem a touch is all


def test_the_key_is_checked():
    with pytest.raises(ConfigError) as err:
        ValidatePlannerConfig(PlannerConfig(max_brush_displacement=-0.01))
    assert "planner.max_brush_displacement" in str(err.value)
    ValidatePlannerConfig(PlannerConfig(max_brush_displacement=0.0))


def test_a_light_brush_is_accepted_and_a_hard_one_refused(robot):
    clear = _Plan(robot, _Ctx(robot))
    assert clear.reason == "" and clear.Row()["brush_displacement"] == 0.0
    # the pads' tips (1.9 cm below the TCP) 3 mm through a level leaf: it
    # is pushed down 3 mm plus the 5 mm margin (the pads poke through it
    # only where the leaf slides off their narrow faces, 4 mm: a sheet is
    # pushed ahead, not pierced)
    light = _Plan(robot, _Ctx(robot, other=_Sheet(-0.016)))
    assert light.reason == "", light.reason
    assert light.Row()["brush_displacement"] == pytest.approx(0.008, abs=0.0015)
    assert light.approach is not None and light.q_grasp is not None
    # 1.7 cm through it: a 2.2 cm push
    hard = _Plan(robot, _Ctx(robot, other=_Sheet(-0.002)))
    assert hard.reason == ("robot-leaf (another leaf) pushed 2.2 cm > "
                           "planner.max_brush_displacement 1.0 cm during the approach"), hard.reason
    assert hard.approach is None
    # a wider bound lets it through; 0 is the old rule: any contact refused
    wide = _Plan(robot, _Ctx(robot, other=_Sheet(-0.002)), max_brush_displacement=0.03)
    assert wide.reason == "" and wide.Row()["brush_displacement"] == pytest.approx(0.022,
                                                                                  abs=0.0015)
    old = _Plan(robot, _Ctx(robot, other=_Sheet(-0.016)), max_brush_displacement=0.0)
    assert old.reason == "robot-leaf during the approach (leaf not between the pads)"


def test_the_grasped_leaf_and_leaves_near_a_fruit_are_never_brushed_nor_near_a_stem_much(robot):
    patch = _Sheet(-0.016)
    held = _Plan(robot, _Ctx(robot, leaf=patch))
    assert held.reason == "robot-leaf during the approach (leaf not between the pads)"
    # a fruit 2.1 cm below the leaf (1.8 cm from the pads: the robot keeps its margins)
    center, radius = P_WG + [0.0, 0.0, -0.047], 0.01

    def sdf(p):
        return np.linalg.norm(np.asarray(p) - center, axis=1) - radius
    near_fruit = _Plan(robot, _Ctx(robot, other=patch, fruit_sdf=sdf))
    assert near_fruit.reason == "robot-leaf (another leaf) near a fruit during the approach", \
        near_fruit.reason
    # without the leaf the fruit is no obstacle: only the leaf rule refused
    assert _Plan(robot, _Ctx(robot, fruit_sdf=sdf)).reason == ""
    # a stem 4 cm beside the pads: the 8 mm push loads the petiole too much there
    stem = P_WG + np.c_[np.full(30, 0.05), np.zeros(30), np.linspace(-0.1, 0.1, 30)]
    near_stem = _Plan(robot, _Ctx(robot, other=patch, branch=stem))
    assert near_stem.reason.startswith("robot-leaf (another leaf) pushed 0.8 cm > 0."), \
        near_stem.reason
    assert "cm from the branch" in near_stem.reason
    assert _Plan(robot, _Ctx(robot, branch=stem)).reason == ""
    # the stem farther away: the same push is allowed
    assert _Plan(robot, _Ctx(robot, other=patch, branch=stem + [0.10, 0, 0])).reason == ""
    # no branch estimate: no lever known, no brushing
    assert _Plan(robot, _Ctx(robot, other=patch, branch=NONE)).reason.startswith("robot-leaf")


def test_the_robot_still_keeps_its_margins_from_the_fruit_and_the_branch(robot):
    """Brushing changes the leaf rule only: a fruit or a stem where the
    pads pass is refused at any ``max_brush_displacement``."""
    center = P_WG + [PAD_EDGE_X + 0.002, 0.022, -0.01]

    def sdf(p):
        return np.linalg.norm(np.asarray(p) - center, axis=1) - 0.005
    for bound in (0.0, 0.01, 0.05):
        why = _Plan(robot, _Ctx(robot, fruit_sdf=sdf), max_brush_displacement=bound).reason
        assert why.startswith("robot-fruit") and "during the approach" in why, why
        stem = SimpleNamespace(**vars(_Ctx(robot)))
        stem.branch_distance = sdf          # the same solid as the completed branch
        why = _Plan(robot, stem, max_brush_displacement=bound).reason
        assert why.startswith("robot-branch"), why


def _Blade(offset_y: float, half: float = 0.02) -> np.ndarray:
    """A blade parallel to the grasped one (the pads close along the
    grasp's y, world -y here) ``offset_y`` m off it, points every 2 mm."""
    a, b = np.meshgrid(np.arange(-half, half + 1e-9, 0.002), np.arange(-half, half + 1e-9, 0.002))
    p_G = np.c_[a.ravel(), np.full(a.size, offset_y), b.ravel()]
    return P_WG + p_G @ R_WG.T


def test_a_leaf_where_the_pads_close_is_counted_and_refuses_the_grasp(robot):
    from lmap_drake.planning.approach import LeafBetweenPads
    half = 0.5 * PlannerConfig().pregrasp_opening
    behind = _Blade(0.010)                   # 1 cm behind the grasped blade
    n = LeafBetweenPads(behind, P_WG, R_WG, half)
    # the pads' 2.2 x 3.8 cm footprint at 2 mm spacing
    assert 100 <= n <= 12 * 20
    assert LeafBetweenPads(_Blade(0.002), P_WG, R_WG, half) == 0    # flush / same blade
    assert LeafBetweenPads(_Blade(half + 0.004), P_WG, R_WG, half) == 0   # beyond the pads
    assert LeafBetweenPads(_Blade(0.010) + R_WG[:, 0] * 0.05, P_WG, R_WG, half) == 0  # aside
    c = _Plan(robot, _Ctx(robot, leaf=_Blade(0.0), other=behind))
    assert not c.feasible and c.reason.startswith("another leaf between the pads")
    c = _Plan(robot, _Ctx(robot, leaf=_Blade(0.0), other=_Blade(0.002)))
    assert not c.reason.startswith("another leaf between the pads")


def test_a_leaf_behind_the_held_one_beside_the_pads_may_pass_between_them(robot):
    """A leaf seen behind the grasped blade (as the camera sees it) at a
    depth the pads close through, within ``hidden_leaf_reach`` of their
    footprint, goes on under the held blade out of sight: refused."""
    from lmap_drake.planning.approach import LeafBetweenPads
    half = 0.5 * PlannerConfig().pregrasp_opening
    p_WC = P_WG + 0.5 * R_WG[:, 1]         # the camera on the blade's front (G's +y)
    aside = R_WG[:, 0] * 0.035             # 1.5-5.5 cm from the TCP along x: beside the pads
    behind, front = _Blade(-0.010) + aside, _Blade(0.010) + aside
    assert LeafBetweenPads(behind, P_WG, R_WG, half) == 0
    n = LeafBetweenPads(behind, P_WG, R_WG, half, hidden_reach=0.02, p_WC=p_WC)
    assert n >= 7 * 20                     # x 1.5-3.1 cm at 2 mm spacing, the blade's 4 cm along z
    # in front of the held blade it would be seen where the pads close: not counted
    assert LeafBetweenPads(front, P_WG, R_WG, half, hidden_reach=0.02, p_WC=p_WC) == 0
    # farther aside than the reach, or deeper than the pads open: not counted
    assert LeafBetweenPads(behind + aside, P_WG, R_WG, half, hidden_reach=0.02, p_WC=p_WC) == 0
    assert LeafBetweenPads(_Blade(-(half + 0.004)) + aside, P_WG, R_WG, half,
                           hidden_reach=0.02, p_WC=p_WC) == 0
    held = _Blade(0.0)
    c = _Plan(robot, _Ctx(robot, leaf=held, other=behind, p_WC=p_WC))
    assert not c.feasible and c.reason.startswith("another leaf may pass between the pads"), c.reason
    for ctx, cfg in ((_Ctx(robot, leaf=held, other=behind, p_WC=p_WC), {"hidden_leaf_reach": 0.0}),
                     (_Ctx(robot, leaf=held, other=front, p_WC=p_WC), {})):
        assert not _Plan(robot, ctx, **cfg).reason.startswith("another leaf"), cfg
