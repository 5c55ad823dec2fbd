"""The arm's joint trajectories (``systems.arm_motion``) without a Diagram:
the pace of the final approach."""
import numpy as np
import pytest
from pydrake.math import RigidTransform

from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.scenario import Scenario
from lmap_drake.robot import UR5_VELOCITY_LIMIT
from lmap_drake.systems.arm_motion import ArmMotions


def test_the_final_approach_keeps_its_tcp_pace_unless_a_wrist_must_turn_fast():
    """Pre-grasp -> grasp: planner.approach_speed sets the TCP's pace (by the
    length of each step, so the shorter steps inserted near a wrist
    singularity take no longer), unless a joint would then exceed half its
    velocity limit (near a singularity)."""
    s = Scenario()
    robot = RobotModel(s.robot.X_WB.GetDeterministicValue())
    c = ArmMotions(s.planner, robot)
    q0 = np.asarray(s.robot.initial_q, float)
    paced = s.planner.pregrasp_distance / s.planner.approach_speed
    X0 = robot.TcpPose(q0)

    def line(n):         # n equal steps along the TCP's axis, pregrasp_distance in all
        out, seed = [], q0
        for k in range(1, n + 1):
            X = RigidTransform(X0.rotation(), X0.translation() + X0.rotation().col(2)
                               * s.planner.pregrasp_distance * k / n)
            seed = robot.Ik(X, seed).q
            out.append(seed)
        return out
    for n in (4, 8):
        small = line(n)
        traj = c.TimePath(0.0, q0, small, **c.ApproachTiming(q0, small))
        assert traj.end_time() == pytest.approx(paced, rel=1e-3)
    wrist = [q0 + np.r_[0, 0, 0, 0, 0, 0.4 * (k + 1)] for k in range(4)]   # wrist 3: the TCP turns in place
    steps = np.linalg.norm(np.diff([robot.TcpPose(q).translation() for q in [q0] + wrist],
                                   axis=0), axis=1)
    traj = c.TimePath(0.0, q0, wrist, **c.ApproachTiming(q0, wrist))
    assert traj.end_time() > 1.3 * steps.sum() / s.planner.approach_speed
    t = np.linspace(0.0, traj.end_time(), 2001)
    qd = np.abs(np.diff([traj.value(x).ravel() for x in t], axis=0)).max() / (t[1] - t[0])
    assert 0.3 * UR5_VELOCITY_LIMIT < qd <= 0.55 * UR5_VELOCITY_LIMIT
    s.planner.approach_speed = 0.5 * s.planner.approach_speed      # slower pace: longer
    small = line(4)
    slow = ArmMotions(s.planner, robot)
    assert slow.TimePath(0.0, q0, small, **slow.ApproachTiming(q0, small)).end_time() \
        == pytest.approx(2 * paced, rel=1e-3)