"""RobotiqClient against a FAKE Robotiq URCap peer: FakeRobotiqServer is a
real TCP server on localhost speaking the URCap ASCII protocol (SET -> ack,
GET VAR -> VAR value) in front of a fake gripper model; no gripper here."""
import socket
import time

import pytest

from fakes.hardware import FakeGripper, FakeRobotiqServer
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


class _StopsOnTheLeafAfterOneRead(FakeGripper):
    """FAKE register model: the fingers close at POS 220 (OBJ 0, moving)
    until the first GET is answered; from then on they stand stopped on the
    leaf at POS 245 (OBJ 2): a gripper that stops between two requests."""

    def __init__(self):
        super().__init__()
        self.regs.update(ACT=1, GTO=1, STA=3, PRE=255, POS=220, OBJ=0)
        self.gets = 0

    def Get(self, var):
        with self.lock:
            value = self.regs.get(var)
            self.gets += 1
            if self.gets == 1:
                self.regs.update(POS=245, OBJ=2)
            return value


def test_the_driver_never_pairs_an_object_flag_with_an_older_opening():
    """The controller holds just inside the opening it measured when the
    gripper reports an object: an opening read before the flag (the fingers
    still moving) would make it command a wider opening than they hold,
    which lets the leaf go. The flag is read first, the opening after it."""
    import numpy as np
    from lmap_drake.station.hardware.systems import RobotiqDriver
    with FakeRobotiqServer(_StopsOnTheLeafAfterOneRead()) as server:
        c = _client(server)
        server.gripper.gets = 0
        opening, obj = c.Measure()
        assert server.received[-2:] == ["GET OBJ", "GET POS"]
        assert (obj, opening) == (0, pytest.approx(PosToOpening(245, c.config)))
        assert c.Measure() == (pytest.approx(PosToOpening(245, c.config)), 2)
        driver = RobotiqDriver(c, 0.05, command=False)
        context = driver.CreateDefaultContext()
        server.gripper.regs.update(POS=220, OBJ=0)
        server.gripper.gets = 0                 # the fingers stop inside the driver's update
        state = driver.EvalUniquePeriodicDiscreteUpdate(context).get_vector(0).get_value()
        assert state[2] == 0.0 and state[0] == pytest.approx(PosToOpening(245, c.config))
        server.gripper.gets = 0
        state = driver.EvalUniquePeriodicDiscreteUpdate(
            driver.CreateDefaultContext()).get_vector(0).get_value()
        assert state[2] == 1.0 and state[0] == pytest.approx(PosToOpening(245, c.config))
        assert np.isfinite(state[1])
        c.Close()
