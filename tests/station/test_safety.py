"""Safety checks in front of the real UR5 (pure functions, no hardware)."""
import numpy as np
import pytest

from lmap_drake.station.hardware.safety import (JointLimitRefusal, NonFiniteCommandRefusal,
                                                SafetyChecker, SafetyRefusal, TcpPositionInBase,
                                                Ur5JointLimitsAndTcpOffset,
                                                VelocityLimitRefusal, WorkspaceRefusal)
from lmap_drake.station.hardware_config import HardwareConfig, UrConfig, ValidateHardwareConfig
from lmap_drake.robot import Ur5DhForwardKinematics

Q_OK = np.array([2.0, -1.9, 1.9, -1.571, -1.571, 0.0])  # the default initial pose


def test_limits_and_tcp_offset_come_from_the_urdf():
    lower, upper, X_FT = Ur5JointLimitsAndTcpOffset()
    assert np.allclose(upper, [2 * np.pi, 2 * np.pi, np.pi, 2 * np.pi, 2 * np.pi, 2 * np.pi])
    assert np.allclose(lower, -upper)
    assert np.allclose(X_FT[:3, 3], [0, 0, 0.144]) and np.allclose(X_FT[:3, :3], np.eye(3))
    # TCP = flange + 0.144 m along the flange z axis.
    T = Ur5DhForwardKinematics(Q_OK)
    assert np.allclose(TcpPositionInBase(Q_OK), T[:3, 3] + 0.144 * T[:3, 2])


def test_valid_command_passes():
    checker = SafetyChecker(UrConfig())
    q = checker.Check(Q_OK + 0.004, Q_OK, 0.01)  # 0.4 rad/s < 0.5 rad/s
    assert np.allclose(q, Q_OK + 0.004)


@pytest.mark.parametrize("bad", [[0.0] * 5, [np.nan, 0, 0, 0, 0, 0], [np.inf, 0, 0, 0, 0, 0]])
def test_refuses_malformed_commands(bad):
    with pytest.raises(NonFiniteCommandRefusal, match="6 finite joint values"):
        SafetyChecker(UrConfig()).Check(bad)


def test_refuses_elbow_beyond_pi():
    q = Q_OK.copy()
    q[2] = 3.2
    with pytest.raises(JointLimitRefusal, match=r"elbow_joint = 3.2000 rad is outside"):
        SafetyChecker(UrConfig()).Check(q)


def test_refuses_shoulder_beyond_two_pi():
    q = Q_OK.copy()
    q[0] = -6.3
    with pytest.raises(JointLimitRefusal, match="shoulder_pan_joint"):
        SafetyChecker(UrConfig()).CheckJointLimits(q)


def test_refuses_too_fast_motion_and_names_the_joint():
    checker = SafetyChecker(UrConfig(joint_speed_limit=0.5))
    q = Q_OK.copy()
    q[4] += 0.006  # 0.6 rad/s over 10 ms
    with pytest.raises(VelocityLimitRefusal, match=r"wrist_2_joint .* 0.600 rad/s, above .* 0.500"):
        checker.Check(q, Q_OK, 0.01)
    checker.Check(q, Q_OK, 0.02)  # the same step over 20 ms is 0.3 rad/s: fine


def test_refuses_tcp_outside_the_workspace_box():
    p = TcpPositionInBase(Q_OK)
    config = UrConfig(workspace_min=[-0.85, -0.85, p[2] + 0.01], workspace_max=[0.85, 0.85, 0.95])
    with pytest.raises(WorkspaceRefusal, match="outside the workspace box on z"):
        SafetyChecker(config).Check(Q_OK)
    config = UrConfig(workspace_max=[p[0] - 0.01, 0.85, 0.95])
    with pytest.raises(WorkspaceRefusal, match="on x"):
        SafetyChecker(config).Check(Q_OK)


def test_refuses_an_elbow_below_the_base_plane_with_the_tcp_inside():
    """Every link is checked, not only the TCP: with the shoulder lifted
    past horizontal the elbow dips below the base plane (DH frame 2 z < 0)
    while the TCP stays well inside the box."""
    from lmap_drake.robot import Ur5DhFrames
    q = np.array([0.0, 0.35, -2.3, -0.5, -1.57, 0.0])
    frames = Ur5DhFrames(q)
    assert frames[2][2, 3] < 0.0                       # the elbow is below the base
    p = TcpPositionInBase(q)
    config = UrConfig(workspace_min=[-0.85, -0.85, 0.02], workspace_max=[0.85, 0.85, 0.95])
    assert np.all(p > config.workspace_min) and np.all(p < config.workspace_max), p
    with pytest.raises(WorkspaceRefusal, match="the elbow at .* on z"):
        SafetyChecker(config).Check(q)


def test_speed_limit_above_ur5_limit_is_rejected():
    with pytest.raises(ValueError, match="UR5 joint limit"):
        SafetyChecker(UrConfig(joint_speed_limit=3.5))
    with pytest.raises(ValueError, match=r"joint_speed_limit .* \(0, pi\]"):
        ValidateHardwareConfig(HardwareConfig(ur=UrConfig(joint_speed_limit=4.0)))


def test_trajectory_check_finds_the_bad_sample():
    checker = SafetyChecker(UrConfig(joint_speed_limit=0.5))
    times = np.arange(0, 1.0, 0.01)
    qs = np.tile(Q_OK, (len(times), 1))
    qs[:, 0] += 0.3 * times  # 0.3 rad/s: fine
    checker.CheckTrajectory(times, qs)
    qs[50:, 0] += 0.01  # one 1 cm jump at sample 50
    with pytest.raises(VelocityLimitRefusal):
        checker.CheckTrajectory(times, qs)


def test_all_refusals_are_safety_refusals():
    for cls in (NonFiniteCommandRefusal, JointLimitRefusal, VelocityLimitRefusal,
                WorkspaceRefusal):
        assert issubclass(cls, SafetyRefusal) and issubclass(cls, RuntimeError)
