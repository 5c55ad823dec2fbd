"""The FEM plant world in Drake: grasp, pulls and the ground-truth outcome
measures. One approach-and-grasp is simulated once; each test forks it."""
import numpy as np
import pytest

from lmap_drake.paths import DEFAULT_SCENARIO_FILE
from lmap_drake.plants.outcome import Summarize
from lmap_drake.plants.leaf_sleep import LeafProximity
from lmap_drake.plants.plant_sim import PlantWorldSim
from lmap_drake.plants.scripted import ApproachAndGrasp, Pull
from lmap_drake.scenario import LoadScenario


@pytest.fixture(scope="module")
def grasped():
    scenario = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="Defaults")
    world = PlantWorldSim(scenario)
    world.Hold(0.3)
    vis0 = world.Visibility()
    X_WT = ApproachAndGrasp(world, scenario.plant_scene.pull)
    return world, vis0, X_WT


def _outcome(world, vis0=0.0):
    return Summarize(world.samples, world.scenario.plant_scene.outcome, vis0, vis0)


def test_grasped_region_follows_the_pads(grasped):
    world = grasped[0].Fork()
    held = world.grasp_state.vertices
    assert len(held) >= 3

    def in_gripper():
        X_GW = world.X_WG().inverse().GetAsMatrix4()
        V = world.LeafVertices()[held]
        return (X_GW @ np.c_[V, np.ones(len(V))].T).T[:, :3]
    ref = in_gripper()
    p0 = world.X_WT().translation()
    worst = 0.0
    direction = np.asarray(world.scenario.plant_scene.pull.direction_W)
    for k in range(6):  # 6 cm in 1 cm steps
        Pull(world, direction, 0.01, 0.3)
        worst = max(worst, np.linalg.norm(in_gripper() - ref, axis=1).max())
    assert np.linalg.norm(world.X_WT().translation() - p0) > 0.055
    assert worst < 0.005


def test_pulling_aside_reveals_the_fruit_safely(grasped):
    world, vis0, _ = grasped
    world = world.Fork()
    pull = world.scenario.plant_scene.pull
    Pull(world, pull.direction_W, pull.distance, pull.duration, 0.3)
    vis1 = world.Visibility()
    assert vis1 > vis0 + 0.3
    out = _outcome(world)
    assert not (out.leaf_damage or out.plant_hazard or out.fruit_collision), out


def test_gentle_pull_is_not_flagged(grasped):
    world = grasped[0].Fork()
    Pull(world, world.scenario.plant_scene.pull.direction_W, 0.02, 1.0, 0.2)
    out = _outcome(world)
    assert not (out.leaf_damage or out.plant_hazard or out.fruit_collision), out


def test_pulling_far_away_from_the_branch_is_flagged(grasped):
    world = grasped[0].Fork()
    away = world.X_WT().translation() - world.model.leaf_attach_W
    away[2] = 0.0
    Pull(world, away, 0.15, 2.0, 0.2)
    out = _outcome(world)
    assert out.leaf_damage or out.plant_hazard, out


def test_pushing_into_the_fruit_is_flagged(grasped):
    world = grasped[0].Fork()
    toward = world.model.fruit_center_W - world.X_WT().translation()
    Pull(world, toward, 0.06, 1.5, 0.2)
    out = _outcome(world)
    assert out.fruit_collision, out


def test_leaf_holds_its_shape_under_gravity():
    scenario = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="Defaults")
    world = PlantWorldSim(scenario)
    fixed = world.model.leaf_fixed
    assert fixed.sum() >= 6 and np.ptp(world.model.leaf_uv[fixed, 1]) > 0.004
    world.Hold(0.5)
    sag = np.linalg.norm(world.LeafVertices() - world.model.leaf_rest_W, axis=1).max()
    assert sag < 0.01


def test_leaf_proximity_agrees_with_every_pairwise_distance():
    """The sleep test's shortcut (bodies' boxes, then samples in the leaf's
    grown box, then a k-d tree) answers as the brute-force distance does,
    for bodies far, near and just either side of the distance."""
    rng = np.random.default_rng(3)
    V = rng.uniform(0, 0.1, size=(200, 3)) * [1, 1, 0.05]
    leaf = LeafProximity(V)
    d = 0.03
    for trial in range(200):
        centre = rng.uniform(-0.1, 0.2, size=3)
        bodies = [centre + rng.normal(scale=0.01, size=(rng.integers(0, 30), 3))
                  for _ in range(3)]
        pts = np.vstack(bodies)
        truth = len(pts) > 0 and bool(
            (np.linalg.norm(pts[:, None] - V[None], axis=2) < d).any())
        assert leaf.Near(bodies, d) == truth, trial
    # one sample 0.1 mm inside and one 0.1 mm outside the distance
    v = V[np.argmax(V[:, 0])]
    assert leaf.Near([np.array([v + [d - 1e-4, 0, 0]])], d)
    assert not leaf.Near([np.array([v + [d + 1e-4, 0, 0]])], d)


def test_leaves_at_rest_far_from_the_robot_sleep_and_wake_when_it_comes():
    """A settled leaf the robot is far from is frozen (its FEM not
    computed) and does not move while asleep; the open gripper 5 cm away at
    the pre-grasp pose leaves it asleep (``sleep_distance`` 3 cm), and
    moving in to grasp wakes it before anything touches it: it wakes
    where it was frozen."""
    from lmap_drake.plants.scripted import TipGraspPose, _LeafNormal
    from lmap_drake.planning.motion import PlanApproach
    scenario = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="Defaults")
    world = PlantWorldSim(scenario)

    def enabled():
        return world.deformable.is_enabled(world.leaf_id,
                                           world.plant.GetMyContextFromRoot(world.context))
    world.Hold(1.0)
    assert not enabled()
    frozen = world.LeafVertices()
    world.Hold(0.2)
    assert np.array_equal(world.LeafVertices(), frozen)
    pull = scenario.plant_scene.pull
    plan = PlanApproach(world.robot, TipGraspPose(world, pull.grasp_from_tip, pull.grasp_v),
                        world.q_cmd, _LeafNormal(world, 0), pull.pregrasp_distance,
                        pull.pregrasp_opening)
    world.SetGripper(pull.pregrasp_opening, 0.0)
    world.MoveJoints([plan.via] + list(plan.to_ready) + list(plan.to_pregrasp), 0.8)
    assert not enabled()
    woke = None
    for q in plan.to_grasp:
        world.MoveJoints([q], 0.8)
        if enabled():
            woke = world.LeafVertices()
            break
    assert woke is not None
    assert np.abs(woke - frozen).max() < 1e-4      # awake before the pads touched it
    # with sleeping off every leaf is always simulated
    scenario.plant_scene.sleep_distance = 0.0
    awake = PlantWorldSim(scenario)
    awake.Hold(1.0)
    assert awake.deformable.is_enabled(awake.leaf_id,
                                       awake.plant.GetMyContextFromRoot(awake.context))


def test_robot_contact_is_reported_with_the_pair():
    """The outcome's robot-contact diagnostic sees the wrist folded into
    the forearm (a pose the planner refuses) and names what touched
    (``worst_robot_contact``)."""
    scenario = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="Defaults")
    world = PlantWorldSim(scenario)
    world.Hold(0.1)
    assert world.worst_robot_contact["force_N"] == 0.0
    folded = np.array(world.q_cmd, float)
    folded[3:5] = [0.5, 3.0]
    assert world.robot.SelfCollision(folded)
    world.MoveJoints([folded], speed_fraction=0.3)
    out = _outcome(world)
    assert out.max_robot_contact_force > 1.0
    assert world.worst_robot_contact["pair"].count("ur5::") + \
        world.worst_robot_contact["pair"].count("robotiq_2f85::") == 2
    assert world.worst_robot_contact["force_N"] == pytest.approx(out.max_robot_contact_force)


def test_release_goes_back_to_the_kept_station_as_a_new_one_would():
    """The station without a grasp is built once: a release switches back
    to it with the state carried over and every leaf awake (the leaf had
    been put to sleep there before the grasp), and the world then moves
    exactly as in a station built anew (a fork, which builds its own)."""
    scenario = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="Defaults")
    world = PlantWorldSim(scenario)
    free = world.station
    world.Hold(1.0)
    assert not world.deformable.is_enabled(world.leaf_id,
                                           world.plant.GetMyContextFromRoot(world.context))
    ApproachAndGrasp(world, scenario.plant_scene.pull)
    assert world.station is not free
    Pull(world, scenario.plant_scene.pull.direction_W, 0.02, 0.5)
    rebuilt = world.Fork()
    t, V = world.time, world.LeafVertices()
    world.Release()
    rebuilt.Release()
    assert world.station is free and rebuilt.station is not free
    assert world.time == t and np.array_equal(world.LeafVertices(), V)
    assert world.deformable.is_enabled(world.leaf_id,
                                       world.plant.GetMyContextFromRoot(world.context))
    world.Hold(0.3)
    rebuilt.Hold(0.3)
    assert np.linalg.norm(world.LeafVertices() - V, axis=1).max() > 1e-4   # released, it moves
    assert np.array_equal(world.LeafVertices(), rebuilt.LeafVertices())


def test_tip_grasp_pose_on_a_coarse_leaf_uses_the_local_plane():
    """A coarse greenhouse leaf (3 cm mesh): the grasp's three nearby mid-surface
    points fall on two vertices; the pose still has the blade's normal as its
    y axis (it was NaN). A fake world (tests only): just the leaf and a mount."""
    from types import SimpleNamespace

    from pydrake.math import RigidTransform

    from lmap_drake.plants.scripted import TipGraspPose
    u, v = np.meshgrid(np.arange(-0.02, 0.131, 0.03), np.arange(-0.03, 0.031, 0.03))
    mid = np.c_[u.ravel(), v.ravel()]
    uv = np.vstack([mid, mid, mid])
    tilt = np.array([0.0, 0.3, 1.0]) / np.linalg.norm([0.0, 0.3, 1.0])   # blade normal
    e_u, e_v = np.array([1.0, 0.0, 0.0]), np.cross(tilt, [1.0, 0.0, 0.0])
    X = 0.6 * np.array([1.0, 0.0, 0.0]) + uv[:, :1] * e_u + uv[:, 1:] * e_v + [0, 0, 0.4]
    leaf = SimpleNamespace(uv=uv, normal_W=tilt)
    world = SimpleNamespace(
        scenario=SimpleNamespace(plant_scene=SimpleNamespace(kind="greenhouse",
                                                             leaf=SimpleNamespace(length=0.1))),
        leaf_refs=[leaf], LeafVertices=lambda j: X, multi=True,
        model=SimpleNamespace(leaves=[leaf]), X_WB=RigidTransform())
    X_WT = TipGraspPose(world, 0.015, 0.0, 0)
    y = X_WT.rotation().matrix()[:, 1]
    assert np.all(np.isfinite(X_WT.GetAsMatrix4()))
    np.testing.assert_allclose(y, tilt, atol=1e-9)
