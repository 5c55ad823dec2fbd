import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from scipy.spatial.transform import Rotation, Slerp

from lmap_drake.planning.motion import CartesianPath


def test_cartesian_path_is_the_straight_line_and_the_slerp():
    rng = np.random.default_rng(0)
    for _ in range(20):
        X0 = RigidTransform(RotationMatrix(RollPitchYaw(rng.uniform(-3, 3, 3))), rng.normal(size=3))
        X1 = RigidTransform(RotationMatrix(RollPitchYaw(rng.uniform(-3, 3, 3))), rng.normal(size=3))
        path = CartesianPath(X0, X1, 0.05)
        n = len(path)
        d = np.linalg.norm(X1.translation() - X0.translation())
        angle = X0.rotation().InvertAndCompose(X1.rotation()).ToAngleAxis().angle()
        assert n == max(1, int(np.ceil(max(d / 0.05, angle / np.deg2rad(10)))))
        slerp = Slerp([0, 1], Rotation.from_matrix([X0.rotation().matrix(),
                                                    X1.rotation().matrix()]))
        for k, X in enumerate(path, 1):
            f = k / n
            assert np.allclose(X.translation(), (1 - f) * X0.translation() + f * X1.translation())
            assert np.allclose(X.rotation().matrix(), slerp(f).as_matrix(), atol=1e-12)
        assert path[-1].IsExactlyEqualTo(X1)


def test_an_approach_is_checked_from_the_grasp_outward_and_stops_at_the_first_blocked_pose():
    import pytest
    from lmap_drake.planning.motion import ApproachBlocked, PlanApproach
    from lmap_drake.planning.robot_model import RobotModel
    from lmap_drake.station.config import RobotConfig
    robot = RobotModel(RobotConfig().X_WB.GetDeterministicValue())
    q0 = np.array(RobotConfig().initial_q)
    X = robot.TcpPose(q0)
    X_grasp = RigidTransform(X.rotation(), X.translation() + X.rotation().col(2) * 0.1)
    seen = []

    def record(segment, q):
        seen.append(segment)
        return ""
    full = PlanApproach(robot, X_grasp, q0, np.array([0.0, -1.0, 0.0]), check=record)
    n = 1 + len(full.to_ready) + len(full.to_pregrasp) + len(full.to_grasp)
    assert len(seen) == n                                  # every solved pose, once
    assert seen[:len(full.to_grasp)] == ["grasp"] * len(full.to_grasp)
    assert set(seen[len(full.to_grasp):]) == {"staging"}
    # blocked at the pre-grasp: nothing beyond it is solved
    calls = []
    ik = robot.Ik

    def counted(*a, **k):
        calls.append(1)
        return ik(*a, **k)
    robot.Ik = counted
    with pytest.raises(ApproachBlocked, match="blocked here"):
        PlanApproach(robot, X_grasp, q0, np.array([0.0, -1.0, 0.0]),
                     check=lambda seg, q: "blocked here" if seg == "staging" else "")
    assert len(calls) == len(full.to_grasp) + 1
    # the memo answers the same requests without solving them again
    memo, calls[:] = {}, []
    a = PlanApproach(robot, X_grasp, q0, np.array([0.0, -1.0, 0.0]), memo=memo)
    solved = len(calls)
    b = PlanApproach(robot, X_grasp, q0, np.array([0.0, -1.0, 0.0]), memo=memo)
    assert len(calls) == solved and np.array_equal(a.via, b.via)
    closer = PlanApproach(robot, X_grasp, q0, np.array([0.0, -1.0, 0.0]), memo=memo,
                          ready_extra=0.02)
    assert len(calls) < 2 * solved                         # the grasp side is shared
    assert all(np.array_equal(p, q) for p, q in zip(closer.to_grasp, a.to_grasp))
    # a narrower opening reuses the solutions: the same joints as solved afresh
    calls[:] = []
    narrow = PlanApproach(robot, X_grasp, q0, np.array([0.0, -1.0, 0.0]), memo=memo,
                          pregrasp_opening=0.011)
    assert calls == []
    fresh = PlanApproach(robot, X_grasp, q0, np.array([0.0, -1.0, 0.0]),
                         pregrasp_opening=0.011)
    assert len(calls) >= n - 1 and narrow.opening == fresh.opening == 0.011
    for seg in ("to_ready", "to_pregrasp", "to_grasp"):
        assert all(np.array_equal(p, q) for p, q in zip(getattr(narrow, seg),
                                                           getattr(fresh, seg)))
    assert np.array_equal(narrow.via, fresh.via)


def test_an_approach_near_a_wrist_singularity_keeps_the_tcp_on_its_line_as_executed():
    """Wrist 2 near 0 at the grasp: one 12.5 mm step of the final approach
    swings wrists 1 and 3 by up to 1 rad, and the joint line between two
    solved poses left the approach line by 3-10 mm (1.9 cm in a multi-fruit
    scene: the open pads brushed the leaf). Inserted waypoints keep the
    timed trajectory within the path tolerance."""
    from lmap_drake.planning.motion import PATH_TOLERANCE, PlanApproach, TimeJointPath
    from lmap_drake.planning.robot_model import RobotModel
    from lmap_drake.station.config import RobotConfig
    robot = RobotModel(RobotConfig().X_WB.GetDeterministicValue())
    q0 = np.array(RobotConfig().initial_q)
    for wrist2 in (0.03, -0.02):
        q_grasp = q0.copy()
        q_grasp[4] = wrist2
        X_grasp = robot.TcpPose(q_grasp)
        z = X_grasp.rotation().col(2)
        a = PlanApproach(robot, X_grasp, q0, X_grasp.rotation().col(1), 0.05, 0.035,
                         ready_extra=0.02)
        assert len(a.to_grasp) > 4                      # 4 poses 12.5 mm apart, plus inserts
        traj = TimeJointPath(0.0, a.to_pregrasp[-1], a.to_grasp)
        off = []
        for t in np.linspace(traj.start_time(), traj.end_time(), 400):
            p = robot.TcpPose(traj.value(t).ravel()).translation() - X_grasp.translation()
            off.append(np.linalg.norm(p - (p @ z) * z))
        assert max(off) < PATH_TOLERANCE + 0.0005, max(off)
        assert np.allclose(robot.TcpPose(a.to_grasp[-1]).GetAsMatrix4(),
                           X_grasp.GetAsMatrix4(), atol=1e-4)


def test_a_step_through_a_fast_wrist_turn_is_straightened_by_continuation():
    """One 12.5 mm step back from a grasp with wrist 2 at 0.02 rad: the IK
    solved from the grasp's joints lands where the joint line between them
    leaves the Cartesian line; the continuation's inserted waypoints and end
    keep it, and the end still solves the step's pose."""
    from lmap_drake.planning.motion import PATH_TOLERANCE, PathDeviation, StraightenStep
    from lmap_drake.planning.robot_model import RobotModel
    from lmap_drake.station.config import RobotConfig
    robot = RobotModel(RobotConfig().X_WB.GetDeterministicValue())
    q_a = np.array(RobotConfig().initial_q)
    q_a[4] = 0.02
    X_a = robot.TcpPose(q_a)
    X_b = RigidTransform(X_a.rotation(), X_a.translation() - 0.0125 * X_a.rotation().col(2))
    r = robot.Ik(X_b, q_a)
    assert r.success
    assert PathDeviation(robot, q_a, r.q, X_a, X_b, 0.0)[0] > PATH_TOLERANCE
    inserted, q_end = StraightenStep(robot, X_a, X_b, q_a, r.q, 0.0)
    assert inserted
    assert np.allclose(robot.TcpPose(q_end).GetAsMatrix4(), X_b.GetAsMatrix4(), atol=1e-4)
    qs = [q_a] + inserted + [q_end]
    poses = [robot.TcpPose(q) for q in qs]
    for u, v, Xu, Xv in zip(qs[:-1], qs[1:], poses[:-1], poses[1:]):
        dist, _ = PathDeviation(robot, u, v, Xu, Xv, 0.0)
        assert dist <= PATH_TOLERANCE
        # every inserted pose lies on the step's line
        p = Xv.translation() - X_a.translation()
        z = X_a.rotation().col(2)
        assert np.linalg.norm(p - (p @ z) * z) < 1e-4


def test_a_path_at_rest_at_its_first_waypoint_keeps_the_free_move_on_its_joint_line():
    """The free move to the via point is checked on the straight joint line
    (``approach.FreeMoveFractions``); through the via point each joint's
    speed comes from its next segments and the joints leave the line."""
    from lmap_drake.planning.motion import TimeJointPath
    q0 = np.zeros(6)
    via = np.array([1.0, 1.0, 0.0, 0.0, 0.0, 0.0])
    after = [via + [0.0, 0.15 * k, 0.0, 0.0, 0.0, 0.0] for k in range(1, 5)]   # joint 1 goes on

    def off_line(traj):
        t1 = traj.get_segment_times()[1]
        Q = np.array([traj.value(t).ravel() for t in np.linspace(0.0, t1, 200)])
        s = Q @ via / (via @ via)
        return float(np.abs(Q - s[:, None] * via).max()), Q[-1]

    through, _ = off_line(TimeJointPath(0.0, q0, [via] + after, 0.5, 0.25))
    at_rest, end = off_line(TimeJointPath(0.0, q0, [via] + after, 0.5, 0.25, rest_at_first=True))
    assert through > 0.05            # the joints out of step (rad)
    assert at_rest < 1e-9 and np.allclose(end, via)
    traj = TimeJointPath(0.0, q0, [via] + after, 0.5, 0.25, rest_at_first=True)
    assert np.allclose(traj.value(traj.end_time()).ravel(), after[-1])
    assert np.allclose(traj.EvalDerivative(traj.get_segment_times()[1], 1).ravel(), 0.0)
