"""RobotiqClient against a FAKE Robotiq URCap peer: FakeRobotiqServer is a
real TCP server on localhost speaking the URCap ASCII protocol (SET -> ack,
GET VAR -> VAR value) in front of a fake gripper model; no gripper here."""
import socket
import time

import pytest

from fakes.hardware import FakeRobotiqServer
from lmap_drake.station.hardware.robotiq_client import (GripperCommandRefusal, OpeningToPos,
                                                        PosToOpening, RobotiqClient, RobotiqError)
from lmap_drake.station.hardware_config import GripperConfig
from lmap_drake.errors import HardwareStationUnavailable


@pytest.fixture
def server():
    with FakeRobotiqServer() as s:  # fake peer on 127.0.0.1, ephemeral port
        yield s


def _client(server, **kw):
    return RobotiqClient.Connect(GripperConfig(port=server.port, timeout=0.5, **kw), "127.0.0.1")


def test_opening_pos_mapping():
    cfg = GripperConfig()
    assert OpeningToPos(0.085, cfg) == 0 and OpeningToPos(0.0, cfg) == 255
    assert OpeningToPos(0.0425, cfg) in (127, 128)
    assert PosToOpening(0, cfg) == pytest.approx(0.085)
    assert PosToOpening(255, cfg) == pytest.approx(0.0)
    cal = GripperConfig(pos_open=3, pos_closed=228)
    for o in (0.0, 0.01, 0.05, 0.085):
        assert PosToOpening(OpeningToPos(o, cal), cal) == pytest.approx(o, abs=0.085 / 225)


def test_activate_then_move_uses_the_real_command_lines(server):
    c = _client(server, speed=200, force=40)
    c.Activate(timeout=2.0)
    assert c.IsActive()
    assert "SET ACT 1" in server.received
    pos = c.MoveToOpening(0.0)
    assert pos == 255
    assert server.received[-1] == "SET POS 255 SPE 200 FOR 40 GTO 1"
    t_end = time.monotonic() + 2.0
    while c.ObjectStatus() != 3 and time.monotonic() < t_end:
        time.sleep(0.01)
    assert c.Position() == 255 and c.Opening() == pytest.approx(0.0)
    assert c.Status() == 3
    c.Close()


def test_already_active_gripper_is_not_reactivated(server):
    c = _client(server)
    c.Activate(timeout=2.0)
    n = len(server.received)
    c.Activate(timeout=2.0)
    assert server.received[n:] == ["GET STA"]  # only checked, no SET ACT


def test_refuses_bad_opening_before_sending(server):
    c = _client(server)
    c.Activate(timeout=2.0)
    n = len(server.received)
    for bad in (0.09, -0.01, float("nan")):
        with pytest.raises(GripperCommandRefusal, match=r"\[0, 0.085\] m"):
            c.MoveToOpening(bad)
    assert server.received[n:] == []


def test_nack_is_an_error(server):
    c = _client(server)
    with pytest.raises(RobotiqError, match="refused 'SET XYZ 1'"):
        c.Set(XYZ=1)


def test_silent_gripper_times_out(server):
    c = _client(server)
    server.silent = True
    with pytest.raises(RobotiqError, match="did not answer 'GET POS' within 0.5 s"):
        c.Position()


def test_lost_connection_is_reported(server):
    c = _client(server)
    assert c.Position() == 0
    server.DropClients()
    with pytest.raises(RobotiqError, match="closed the connection|lost the connection"):
        c.Position()
        c.Position()


def test_nothing_listening_gives_clear_error():
    with socket.socket() as s:  # find a free port, then close it
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(HardwareStationUnavailable, match=f"Robotiq gripper socket at 127.0.0.1:{port}"):
        RobotiqClient.Connect(GripperConfig(port=port, timeout=0.5), "127.0.0.1")
