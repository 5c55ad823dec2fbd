"""UrClient over FAKE ur_rtde interfaces (FakeRTDEControlInterface /
FakeRTDEReceiveInterface from tests/fakes/hardware.py: same method
names and argument orders as ur_rtde; no robot is involved)."""
import sys
import time

import numpy as np
import pytest

from fakes.hardware import MakeFakeUrClient
from lmap_drake.station.hardware.safety import (HardwareAbort, JointLimitRefusal,
                                                VelocityLimitRefusal, WorkspaceRefusal)
from lmap_drake.station.hardware.ur_client import ConnectUr
from lmap_drake.station.hardware_config import UrConfig
from lmap_drake.errors import HardwareStationUnavailable

Q0 = np.array([2.0, -1.9, 1.9, -1.571, -1.571, 0.0])


def _wait(cond, timeout=2.0):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if cond():
            return True
        time.sleep(0.005)
    return False


@pytest.fixture
def client():
    c = MakeFakeUrClient(UrConfig(), Q0)  # a fake robot behind fake ur_rtde interfaces
    yield c
    c.Close()


def test_missing_ur_rtde_gives_install_hint(monkeypatch):
    monkeypatch.setitem(sys.modules, "rtde_control", None)  # import fails like a missing lib
    with pytest.raises(HardwareStationUnavailable, match=r"pip install -e \.\[hardware\]"):
        ConnectUr(UrConfig())


def test_reads_state(client):
    q, v = client.ReadState()
    assert np.allclose(q, Q0) and v.shape == (6,)


def test_streams_servoj_with_configured_parameters_and_reaches_target(client):
    cfg = client.config
    target = Q0 + np.array([0.004, 0, 0, 0, 0, -0.004])
    client.SetTarget(target, 0.01)
    assert _wait(lambda: np.allclose(client.receive.q, target, atol=1e-9))
    q, speed, acc, t, lookahead, gain = client.control.servoj_calls[0]
    assert (speed, acc, t, lookahead, gain) == (cfg.joint_speed_limit, cfg.joint_acceleration_limit,
                                                1.0 / cfg.rtde_frequency,
                                                cfg.servo_lookahead_time, cfg.servo_gain)
    # Interpolated, never faster than the speed limit between servo ticks.
    qs = np.array(client.control.servoed_qs)
    steps = np.abs(np.diff(np.vstack([Q0, qs]), axis=0)).max()
    assert steps <= cfg.joint_speed_limit / cfg.rtde_frequency + 1e-12
    assert len(qs) > 3


def test_refused_command_never_reaches_servoj_and_stops_the_arm(client):
    bad = Q0.copy()
    bad[2] = 3.3
    with pytest.raises(JointLimitRefusal):
        client.SetTarget(bad, 0.01)
    assert client.control.servoj_calls == []
    assert client.control.servo_stops and client.control.script_stops == 1
    with pytest.raises(HardwareAbort):  # the client stays stopped
        client.SetTarget(Q0, 0.01)


def test_first_command_far_from_the_arm_is_refused(client):
    with pytest.raises(VelocityLimitRefusal, match="shoulder_pan_joint"):
        client.SetTarget(Q0 + np.array([0.2, 0, 0, 0, 0, 0]), 0.01)
    assert client.control.servoj_calls == []


def test_workspace_refusal_through_the_client():
    c = MakeFakeUrClient(UrConfig(workspace_min=[-0.85, -0.85, 0.5]), Q0)
    with pytest.raises(WorkspaceRefusal):
        c.SetTarget(Q0, 0.01)
    assert c.control.servoj_calls == []


def test_protective_stop_aborts_and_stops(client):
    client.SetTarget(Q0, 0.01)
    assert _wait(lambda: len(client.control.servoj_calls) > 2)
    client.receive.protective_stopped = True
    assert _wait(lambda: client.control.script_stops == 1)
    assert not client.streaming and client.control.servo_stops
    n = len(client.control.servoj_calls)
    with pytest.raises(HardwareAbort, match="protective stopped.*the arm was stopped"):
        client.ReadState()
    time.sleep(0.02)
    assert len(client.control.servoj_calls) == n  # nothing streamed after the stop


def test_emergency_stop_aborts():
    c = MakeFakeUrClient(UrConfig(), Q0)
    c.receive.emergency_stopped = True
    with pytest.raises(HardwareAbort, match="emergency stopped"):
        c.SetTarget(Q0, 0.01)
    assert c.control.servoj_calls == [] and c.control.script_stops == 1


def test_lost_connection_aborts_with_clear_message(client):
    client.SetTarget(Q0, 0.01)
    client.receive.connected = False
    assert _wait(lambda: client.control.script_stops == 1)
    with pytest.raises(HardwareAbort, match="lost the RTDE connection to the UR5 at 192.168.1.102"):
        client.ReadState()


def test_read_failure_aborts():
    c = MakeFakeUrClient(UrConfig(), Q0)
    c.receive.fail_reads = True
    with pytest.raises(HardwareAbort, match="reading the UR5 joint state failed"):
        c.ReadState()


def test_read_only_client_cannot_command():
    c = MakeFakeUrClient(UrConfig(), Q0, read_only=True)
    assert np.allclose(c.ReadState()[0], Q0)
    with pytest.raises(HardwareAbort, match="read-only"):
        c.SetTarget(Q0, 0.01)
    c.Close()


def test_close_stops_script_and_disconnects(client):
    client.SetTarget(Q0, 0.01)
    client.Close()
    assert not client.streaming
    assert client.control.script_stops == 1 and not client.control.connected
    assert not client.receive.connected
    client.Close()  # idempotent
    assert client.control.script_stops == 1
