import numpy as np
import pytest
import trimesh
from pydrake.math import RigidTransform, RotationMatrix

from lmap_drake.deformation.action import Action
from lmap_drake.planning.collision import LeafCollisionReason, RobotCollisionReason
from lmap_drake.planning.result import Candidate
from lmap_drake.planning.selection import SelectAction
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.station.config import RobotConfig


@pytest.fixture(scope="module")
def robot():
    return RobotModel(RobotConfig().X_WB.GetDeterministicValue())


def test_ik_reaches_poses(robot):
    rng = np.random.default_rng(3)
    q0 = np.array(RobotConfig().initial_q)
    for _ in range(10):
        q_true = q0 + rng.uniform(-0.4, 0.4, 6)
        X = robot.TcpPose(q_true)
        r = robot.Ik(X, q0)
        assert r.success, r.reason
        X_got = robot.TcpPose(r.q)
        assert np.linalg.norm(X_got.translation() - X.translation()) < 0.002
        assert X_got.rotation().InvertAndCompose(X.rotation()).ToAngleAxis().angle() < 0.02


def test_gripper_through_the_fruit_is_rejected(robot):
    # TCP in front of the plant, approaching along +x with the pads closing
    # along y; a fruit-sized sphere 10 cm ahead of the TCP.
    R = RotationMatrix(np.array([[0.0, 0, 1], [0, -1, 0], [1, 0, 0]]))
    X = RigidTransform(R, [0.40, -0.07, 0.31])
    r0 = robot.Ik(X, np.array(RobotConfig().initial_q), multistart=True)
    assert r0.success, r0.reason
    center, radius = X.translation() + [0.10, 0, 0], 0.03
    sdf = lambda p: np.linalg.norm(p - center, axis=1) - radius  # noqa: E731
    assert RobotCollisionReason(robot.SurfacePoints(r0.q), sdf, None, 0.005) == ""
    # drive the TCP 8 cm forward, into the fruit
    r = robot.Ik(RigidTransform(R, X.translation() + [0.08, 0, 0]), r0.q)
    assert r.success
    why = RobotCollisionReason(robot.SurfacePoints(r.q), sdf, None, 0.005)
    assert why.startswith("robot-fruit")
    # The same solid as a branch distance: named as the branch; the fruit is
    # checked first when both are hit.
    assert RobotCollisionReason(robot.SurfacePoints(r.q), None, sdf, 0.005).startswith(
        "robot-branch")
    assert RobotCollisionReason(robot.SurfacePoints(r.q), sdf, sdf, 0.005).startswith(
        "robot-fruit")
    far = (center - 1.0, center - 0.9)     # bounds away from the robot: nothing queried
    assert RobotCollisionReason(robot.SurfacePoints(r.q), sdf, sdf, 0.005, far, far) == ""


def test_leaf_pushed_into_the_fruit_is_rejected():
    center, radius = np.zeros(3), 0.035
    sdf = lambda p: np.linalg.norm(p - center, axis=1) - radius  # noqa: E731
    leaf = np.c_[np.linspace(-0.02, 0.02, 20), np.full(20, -0.06), np.zeros(20)]
    assert LeafCollisionReason(leaf, leaf + [0, 0, 0.02], sdf, 0.005) == ""
    assert LeafCollisionReason(leaf, leaf + [0, 0.03, 0], sdf, 0.005).startswith("leaf")


def test_leaf_swung_into_a_branch_is_rejected_but_not_its_petiole_base():
    from lmap_drake.planning.collision import BranchDistance
    cyl = trimesh.creation.cylinder(0.005, segment=[[0, 0, -0.2], [0, 0, 0.2]])
    dist = BranchDistance(cyl.vertices, cyl.faces)
    # a blade from 2 cm to 8 cm in front of the stem along +x, its base
    # point resting on it (the petiole's base)
    leaf = np.c_[np.linspace(0.02, 0.08, 25), np.zeros(25), np.zeros(25)]
    leaf = np.vstack([[0.009, 0, 0], leaf])
    # moved along the stem: nothing; pushed onto it: rejected
    assert LeafCollisionReason(leaf, leaf + [0, 0, 0.03], dist, 0.005, what="branch",
                               ignore_touching=True) == ""
    onto = leaf.copy()
    onto[1:, 0] -= 0.02                   # the blade slid 2 cm toward the stem
    why = LeafCollisionReason(leaf, onto, dist, 0.005, what="branch", ignore_touching=True)
    assert why.startswith("leaf-branch")
    # the base point alone moving closer: not counted with ignore_touching
    base = leaf.copy()
    base[0, 0] = 0.0055
    assert LeafCollisionReason(leaf, base, dist, 0.005, what="branch",
                               ignore_touching=True) == ""
    assert LeafCollisionReason(leaf, base, dist, 0.005, what="branch").startswith("leaf-branch")


def _cand(n_vis, energy):
    a = Action(np.zeros(3), np.eye(3), np.array([0.02, 0, 0]))
    return Candidate(a, 0, n_vis=n_vis, energy=energy)


def test_energy_weight_changes_the_choice():
    """The most revealing action stretches the leaf hard: lambda = 0 takes
    it, lambda = 1 prefers a gentler action that reveals almost as much."""
    hard, gentle, useless = _cand(500, 0.05), _cand(430, 0.005), _cand(50, 0.001)
    assert SelectAction([hard, gentle, useless], 0.0) is hard
    assert SelectAction([hard, gentle, useless], 1.0) is gentle


def test_newton_ik_agrees_with_drake_ik_and_respects_limits(robot):
    from lmap_drake.planning.ik import NewtonTcpIk, SolveTcpIk
    from pydrake.math import RollPitchYaw
    rng = np.random.default_rng(7)
    q0 = np.array(RobotConfig().initial_q)
    context = robot.plant.CreateDefaultContext()
    agree = 0
    for _ in range(20):
        q_seed = q0 + rng.uniform(-0.4, 0.4, 6)
        X = robot.TcpPose(q_seed)
        X_target = RigidTransform(
            RollPitchYaw(rng.uniform(-0.2, 0.2, 3)).ToRotationMatrix().multiply(X.rotation()),
            X.translation() + rng.uniform(-0.05, 0.05, 3))
        a = NewtonTcpIk(robot.plant, context, X_target, q_seed)
        b = SolveTcpIk(robot.plant, X_target, q_seed, gripper_half_opening=0.0)
        assert a.success == b.success
        if a.success:
            X_got = robot.TcpPose(a.q)
            assert np.linalg.norm(X_got.translation() - X_target.translation()) < 1e-4
            agree += np.abs(a.q - b.q).max() < 1e-2   # the seed's solution branch
    assert agree >= 18
    # out of reach (2 m away): Newton reports failure, it does not return junk
    far = RigidTransform(X.rotation(), X.translation() + [2.0, 0, 0])
    assert not NewtonTcpIk(robot.plant, context, far, q0).success
    # a target whose only nearby solution needs the shoulder past its limit
    lo = robot.plant.GetPositionLowerLimits()[:6]
    q_out = q0.copy()
    q_out[0] = lo[0] - 0.2
    r = NewtonTcpIk(robot.plant, context, robot.TcpPose(q_out), np.r_[lo[0] + 0.01, q0[1:]])
    assert not r.success or np.all(r.q >= lo)


def test_self_collision_names_the_pair(robot):
    """The arm folded onto the gripper is a self-collision (the planner's
    plant and SceneGraph), the ready pose is not; the gripper's own parts
    never count."""
    home = np.array([0.0, -1.57, 1.57, -1.57, -1.57, 0.0])
    assert robot.SelfCollision(home) == ""
    assert robot.SelfCollision(home, half_opening=0.0) == ""   # pads closed on nothing
    folded = np.array([0.0, -1.57, 1.57, 0.5, 3.0, 0.0])
    pair = robot.SelfCollision(folded)
    assert "forearm" in pair and "robotiq_2f85" in pair


def test_self_collision_keeps_a_margin_between_distant_links(robot):
    """With ``SELF_MARGIN`` (the approach's check) links three or more
    joints apart must keep it: some poses that do not interpenetrate are
    refused for it; the ready pose keeps it."""
    from lmap_drake.planning.robot_model import SELF_MARGIN
    assert SELF_MARGIN > 0
    rng = np.random.default_rng(0)
    close = [q for q in rng.uniform(-np.pi, np.pi, (300, 6))
             if robot.SelfCollision(q) == "" and robot.SelfCollision(q, margin=SELF_MARGIN)]
    assert close
    assert robot.SelfCollision(np.array(RobotConfig().initial_q), margin=SELF_MARGIN) == ""


def test_planner_rejects_a_self_colliding_pose(robot):
    """A pose whose joints fold the wrist into the forearm is refused with
    the pair named, even far from the fruit and the branch."""
    from types import SimpleNamespace
    from lmap_drake.planning.robot_checks import RobotPoseReason
    from lmap_drake.planning.config import PlannerConfig
    ctx = SimpleNamespace(fruit_sdf=None, branch_distance=None, fruit_box=None, branch_box=None)
    home = np.array([0.0, -1.57, 1.57, -1.57, -1.57, 0.0])
    folded = np.array([0.0, -1.57, 1.57, 0.5, 3.0, 0.0])
    cfg = PlannerConfig()
    assert RobotPoseReason(robot, home, 0.0, robot.SurfacePoints(home), ctx, cfg) == ""
    why = RobotPoseReason(robot, folded, 0.0, robot.SurfacePoints(folded), ctx, cfg)
    assert why.startswith("robot self-collision") and "forearm" in why


def test_surface_samples_by_body_are_the_surface_points_inside_their_boxes(robot):
    q = np.array([0.3, -1.2, 1.4, -1.8, -1.5, 0.2])
    per = robot.SurfacePointsByBody(q, 0.02)
    np.testing.assert_array_equal(np.vstack([per[i] for i in range(len(per))]),
                                  robot.SurfacePoints(q, 0.02))
    for i in range(len(per)):
        lo, hi = per.boxes[i]
        assert np.all(per[i] >= lo - 1e-12) and np.all(per[i] <= hi + 1e-12)
    with pytest.raises(IndexError):
        per[len(per)]


def test_a_ready_pose_beyond_reach_is_brought_closer(robot):
    """The approach comes in along the gripper's axis from a ready pose
    behind the pre-grasp. Near the edge of the arm's reach the default 8 cm
    ready pose has no IK (a failure of the staging, not of the grasp); the
    planner then tries the next of ``ready_distances`` and keeps the grasp."""
    from types import SimpleNamespace
    from lmap_drake.planning.approach import IkAndRobotChecks
    from lmap_drake.planning.motion import MotionError, PlanApproach
    from lmap_drake.planning.config import PlannerConfig
    R = np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]])    # approaching from above
    p = RobotConfig().X_WB.GetDeterministicValue().translation() + [0.50, 0.0, 0.30]
    q0 = np.array(RobotConfig().initial_q)
    with pytest.raises(MotionError) as err:
        PlanApproach(robot, RigidTransform(RotationMatrix(R), p), q0, np.array([0, -1.0, 0]),
                     0.05, 0.035, ready_extra=0.08)
    assert err.value.staging
    none = np.zeros((0, 3))
    ctx = SimpleNamespace(robot=robot, q_current=q0, leaf_W=none, other_leaves_W=none,
                          fruit_sdf=None, branch_distance=None, fruit_box=None, branch_box=None)
    grasp = SimpleNamespace(p_WG=p, R_WG=R, grasp_id=0)
    pull = Action(p, R, dp_W=np.array([0.0, 0.0, 0.02]), grasp_id=0, direction_id=0)
    far = IkAndRobotChecks(ctx, grasp, PlannerConfig(ready_distances=[0.08]), [pull])
    # (each pose is checked as it is solved, from the grasp outward: the
    # forearm meets the gripper on the way to that ready pose before its IK
    # fails; either is a failure of the staging)
    assert (far[0].reason.startswith("IK failed (staging)")
            or far[0].reason.endswith("on the way to the pre-grasp")), far[0].reason
    assert far[0].approach is None
    assert PlannerConfig().ready_distances == [0.08, 0.02]      # the fallback is the default
    (c,) = IkAndRobotChecks(ctx, grasp, PlannerConfig(), [pull])
    assert c.approach is not None and not c.reason.startswith("IK failed"), c.reason
    assert c.Row()["ready_distance"] == 0.02
    X_ready = robot.TcpPose(c.approach.to_ready[-1])
    assert np.linalg.norm(X_ready.translation() - (p + [0, 0, 0.07])) < 0.003
    X_grasp = robot.TcpPose(c.approach.to_grasp[-1])
    assert np.linalg.norm(X_grasp.translation() - p) < 0.002


def test_a_free_joint_move_is_checked_every_centimetre(robot):
    """The joint move to the via pose (and the retreat's last move back) is
    checked at poses no robot point moves more than ``FREE_MOVE_STEP``
    between; eight even samples let the wrist skip many centimetres."""
    from lmap_drake.planning.approach import FREE_MOVE_STEP, FreeMoveFractions
    q0 = np.array(RobotConfig().initial_q)
    q1 = q0 + np.array([0.8, -0.5, 0.6, 0.4, 0.9, 1.2])

    def largest_move(fractions):
        C = np.stack([robot.SurfacePointsByBody(q0 + f * (q1 - q0), 0.0175).corners
                      for f in fractions])
        return np.linalg.norm(np.diff(C, axis=0), axis=-1).max()
    f = FreeMoveFractions(robot, q0, q1, 0.0175)
    assert np.all((f > 0) & (f < 1)) and np.all(np.diff(f) > 0)
    assert largest_move(np.r_[0.0, f, 1.0]) <= FREE_MOVE_STEP + 1e-9
    assert largest_move(np.linspace(0, 1, 8)) > 5 * FREE_MOVE_STEP
    # a short move needs no more than the eight
    near = FreeMoveFractions(robot, q0, q0 + 0.001, 0.0175)
    assert len(near) == 6


def test_the_chosen_action_is_checked_along_the_path_the_controller_will_execute(robot):
    """A candidate's own checks see its end (and an arc's midway) pose; the
    chosen one is also checked at every waypoint of ``PlanActionPath``, the
    path the controller runs: a fruit crossed halfway along a straight pull
    refuses it."""
    from types import SimpleNamespace
    from lmap_drake.planning.robot_checks import ActionPathReason
    from lmap_drake.planning.config import PlannerConfig
    R = np.array([[0.0, 0, 1], [0, -1, 0], [1, 0, 0]])
    p = np.array([0.40, -0.07, 0.31])
    r0 = robot.Ik(RigidTransform(RotationMatrix(R), p), np.array(RobotConfig().initial_q),
                  multistart=True)
    assert r0.success, r0.reason
    pull = Action(p, R, dp_W=np.array([0.0, 0.0, 0.16]), grasp_id=0, direction_id=0)
    c = Candidate(pull, 0)
    c.q_grasp = r0.q
    none = np.zeros((0, 3))

    def ctx_with(center):
        sdf = None if center is None else (
            lambda q: np.linalg.norm(q - center, axis=1) - 0.01)
        box = None if center is None else (center - 0.01, center + 0.01)
        return SimpleNamespace(robot=robot, fruit_sdf=sdf, fruit_box=box, branch_distance=None,
                               branch_box=None, other_leaves_W=none)
    cfg = PlannerConfig()
    assert ActionPathReason(ctx_with(None), cfg, c) == ""
    # a small fruit 4 cm behind the TCP (in the gripper's body) halfway up a
    # 16 cm pull
    center = p + [-0.04, 0.0, 0.08]
    for q in (r0.q, robot.Ik(RigidTransform(RotationMatrix(R), p + pull.dp_W), r0.q).q):
        assert RobotCollisionReason(robot.SurfacePointsByBody(q, 0.0),
                                    ctx_with(center).fruit_sdf, None, cfg.collision_margin,
                                    body_fruit_margin=cfg.robot_fruit_margin) == ""
    why = ActionPathReason(ctx_with(center), cfg, c)
    assert why.startswith("robot-") and why.endswith("along the executed pull"), why


def test_deeper_grasps_are_tried_only_while_too_few_grasps_pass(robot):
    """When fewer than ``min_usable_grasps`` grasps pass, the grasp set is
    made again at each of ``deeper_grasp_insets`` in turn: the added grasps
    (ids 100 + i) lie that far inside the leaf's outline and pass their
    approach; once enough pass, no further set is made; with enough passing
    already, nothing is added."""
    from types import SimpleNamespace
    from scipy.spatial import ConvexHull
    from lmap_drake.deformation.synthetic import OvateLeaf
    from lmap_drake.planning.candidates import GraspCandidates, LeafPca
    from lmap_drake.planning.attachment import EstimateHinge
    from lmap_drake.planning.candidates import DEEPER_GRASP_IDS, DeeperGrasps
    from lmap_drake.planning.result import CandidateSet
    from lmap_drake.planning.config import PlannerConfig
    from lmap_drake.planning.candidates import PullDirections
    leaf, branch = OvateLeaf()
    # the blade hanging in front of the robot, the camera 60 cm in front of it
    base = RobotConfig().X_WB.GetDeterministicValue().translation()
    R = np.array([[0.0, 0, 1], [1, 0, 0], [0, 1, 0]])         # leaf x -> world z (hangs)
    offset = base + [0.5, -0.05, 0.30]
    leaf_W, branch_W = leaf @ R.T + offset, branch @ R.T + offset
    none = np.zeros((0, 3))
    ctx = SimpleNamespace(robot=robot, q_current=np.array(RobotConfig().initial_q),
                          leaf_W=leaf_W, branch_all_W=branch_W, p_WC=offset + [0, -0.6, 0.1],
                          other_leaves_W=none, fruit_sdf=None, branch_distance=None,
                          fruit_box=None, branch_box=None)
    cfg = PlannerConfig(action_families=["twist"], deeper_grasp_insets=[0.02, 0.03])
    pivot = EstimateHinge(leaf_W, branch_W)
    out = CandidateSet("ok", None)
    DeeperGrasps(ctx, cfg, out, pivot, np.zeros(0), PullDirections())
    ids = {c.action.grasp_id for c in out.candidates}
    assert ids and all(DEEPER_GRASP_IDS <= i < 2 * DEEPER_GRASP_IDS for i in ids)
    assert len({c.action.grasp_id for c in out.candidates if c.feasible}) >= 3
    assert all(c.approach is not None for c in out.candidates)
    frame = LeafPca(leaf_W, ctx.p_WC)
    hull = ConvexHull(frame.To2d(leaf_W))

    def inside(p_W):             # distance inside the outline (the hull's edges)
        q = frame.To2d(np.reshape(p_W, (1, 3)))[0]
        return -np.max(hull.equations[:, :2] @ q + hull.equations[:, 2])
    rim, _ = GraspCandidates(leaf_W, branch_W, ctx.p_WC, cfg.num_grasps, cfg.grasp_inset,
                             cfg.min_branch_distance)
    deep = {c.action.grasp_id: inside(c.action.p_WG) for c in out.candidates}
    assert (np.median(list(deep.values()))
            > np.median([inside(g.p_WG) for g in rim]) + 0.007)      # ~1 cm deeper
    enough = CandidateSet("ok", None, candidates=list(out.candidates))
    DeeperGrasps(ctx, cfg, enough, pivot, np.zeros(0), PullDirections())
    assert len(enough.candidates) == len(out.candidates)
