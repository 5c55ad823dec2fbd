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
    from lmap_drake.scenario import RobotConfig
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
