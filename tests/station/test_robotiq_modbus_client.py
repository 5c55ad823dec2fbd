"""RobotiqModbusClient (real pymodbus client) against a FAKE 2F-85 Modbus RTU
slave: ``fakes.modbus.FakeModbusGripperServer``, a real pymodbus serial
server on a pseudo-terminal pair in front of the project's fake gripper
model; no gripper here. The frames on the line are checked against the
2F-85 manual's examples."""
import dataclasses as dc
import json
import sys
import time

import pytest

from fakes.hardware import FakeGripper, FakeRobotiqServer
from fakes.modbus import FakeModbusGripperServer
from lmap_drake.errors import HardwareStationUnavailable
from lmap_drake.scenario import LoadScenario, ScenarioError
from lmap_drake.station.hardware.robotiq_client import (GripperCommandRefusal, PosToOpening,
                                                        RobotiqClient)
from lmap_drake.station.hardware.robotiq_modbus_client import (RequestRegisters,
                                                               RobotiqError, RobotiqFault,
                                                               RobotiqModbusClient,
                                                               StatusFromRegisters)
from lmap_drake.station.hardware.safety import HardwareAbort
from lmap_drake.station.hardware.station import CheckHardwareSetup, ConnectGripper
from lmap_drake.station.hardware_config import (GripperConfig, HardwareConfig,
                                                ValidateHardwareConfig)

LEAF_POS = 200      # where the fake fingers stall on an object


@pytest.fixture
def server():
    with FakeModbusGripperServer(FakeGripper(object_pos=LEAF_POS)) as s:
        yield s


def _client(server, **kw) -> RobotiqModbusClient:
    kw = {"timeout": 1.0, "retries": 1, **kw}      # generous: the machine may be loaded
    return RobotiqModbusClient.Connect(GripperConfig(link="modbus_rtu",
                                                     serial_device=server.device, **kw))


def _Wait(cond, timeout=2.0):
    t_end = time.monotonic() + timeout
    while not cond() and time.monotonic() < t_end:
        time.sleep(0.01)
    return cond()


def test_register_layout_is_the_manuals():
    # manual: close at full speed and force = 09 10 03E8 0003 06 | 0900 00FF FFFF
    req = {"ACT": 1, "GTO": 1, "ATR": 0, "ADR": 0, "POS": 255, "SPE": 255, "FOR": 255}
    assert RequestRegisters(req) == [0x0900, 0x00FF, 0xFFFF]
    # manual: grip completed = 09 03 06 | B900 00FF BD00: gOBJ 2 at position 0xBD
    st = StatusFromRegisters([0xB900, 0x00FF, 0xBD00])
    assert st == {"ACT": 1, "GTO": 1, "STA": 3, "OBJ": 2, "FLT": 0, "KFLT": 0, "PRE": 255,
                  "POS": 0xBD, "CUR": 0}
    assert StatusFromRegisters([0x1100, 0, 0])["STA"] == 1           # activation in progress
    assert StatusFromRegisters([0, 0x0E00, 0])["FLT"] == 0x0E


def test_activation_then_a_move_sends_the_manuals_frames(server):
    c = _client(server, speed=255, force=255)
    assert not c.IsActive()
    c.Activate(timeout=2.0)
    assert c.IsActive() and c.Status() == 3
    assert server.writes[:2] == [[0x0000, 0x0000, 0xFFFF], [0x0100, 0x0000, 0xFFFF]]
    assert c.MoveToOpening(0.0) == 255
    # the manual's frame for "close at full speed and force", CRC included
    assert bytes.fromhex("09 10 03 E8 00 03 06 09 00 00 FF FF FF 42 29") in server.wire
    # and its status read of the three input registers
    assert bytes.fromhex("09 03 07 D0 00 03 04 0E") in server.wire
    c.Close()


def test_a_close_on_an_object_reports_it_and_where_it_stalled(server):
    c = _client(server, speed=200, force=40)
    c.Activate(timeout=2.0)
    c.MoveToOpening(0.0)
    assert server.writes[-1] == [0x0900, 0x00FF, 200 << 8 | 40]
    assert _Wait(lambda: c.ObjectStatus() != 0)
    assert c.ObjectStatus() == 2                 # stopped on an object while closing
    assert c.Position() == LEAF_POS and c.Get("PRE") == 255
    assert c.Opening() == pytest.approx(PosToOpening(LEAF_POS, c.config))
    n = len(server.wire)
    assert c.Measure() == (pytest.approx(PosToOpening(LEAF_POS, c.config)), 2)
    assert server.wire[n:].count(bytes.fromhex("09 03 07 D0 00 03 04 0E")) == 1   # one read
    c.MoveToOpening(0.085)                       # open again: nothing in the way
    assert _Wait(lambda: c.ObjectStatus() == 3) and c.Position() == 0


def test_an_active_gripper_is_not_reset_and_keeps_its_request(server):
    c = _client(server)
    c.Activate(timeout=2.0)
    c.MoveToPos(100)
    c.Close()
    n = len(server.writes)
    c = _client(server)                           # a new connection to the active gripper
    c.Activate(timeout=2.0)
    assert len(server.writes) == n                # only read
    c.Set(SPE=10)                                 # a write keeps rACT, rGTO and rPR
    assert server.writes[-1][:2] == [0x0900, 100]


def test_bad_opening_and_unknown_fields_are_refused_before_sending(server):
    c = _client(server)
    c.Activate(timeout=2.0)
    n = len(server.received)
    for bad in (0.09, -0.01, float("nan")):
        with pytest.raises(GripperCommandRefusal, match=r"\[0, 0.085\] m"):
            c.MoveToOpening(bad)
    with pytest.raises(RobotiqError, match="unknown gripper request field 'XYZ'"):
        c.Set(XYZ=1)
    assert server.received[n:] == []


def test_a_gripper_fault_is_a_clear_error_and_a_reactivation_clears_it(server):
    c = _client(server)
    c.Activate(timeout=2.0)
    server.gripper.regs["FLT"] = 0x0E
    with pytest.raises(RobotiqFault, match=r"fault 0x0E \(overcurrent triggered\)") as err:
        c.Opening()
    assert isinstance(err.value, HardwareAbort) and "\n" not in str(err.value)
    assert c.Fault() == 0x0E
    n = len(server.writes)
    with pytest.raises(RobotiqFault):
        c.MoveToPos(255)                          # a gripper in fault gets no request
    assert len(server.writes) == n
    server.gripper.regs["FLT"] = 0x09             # "no communication for 1 s": not an abort
    assert c.Position() == 0
    server.gripper.regs["FLT"] = 0x0E
    c.Activate(timeout=2.0)                       # reset + activation clears the fault
    assert c.Fault() == 0 and c.IsActive()


@pytest.mark.parametrize("how", ["Stop", "Unplug"])
def test_a_lost_link_is_reported(server, how):
    c = _client(server, timeout=0.3, retries=1)
    c.Activate(timeout=2.0)
    n = len(server.writes)
    getattr(server, how)()
    t0 = time.monotonic()
    with pytest.raises(RobotiqError, match=r"lost the link to the gripper on /dev/.*slave 9.*"
                                           r"no reply to the status read .* within 0.3 s "
                                           r"\(2 tries\)"):
        c.Position()
    assert time.monotonic() - t0 < 2.0
    with pytest.raises(RobotiqError, match="lost the link"):
        c.MoveToPos(255)
    assert len(server.writes) == n


def test_connect_errors_say_what_to_check(server, tmp_path):
    with pytest.raises(HardwareStationUnavailable, match=r"serial device /nonexistent/ttyUSB7 "
                                                         r"does not exist"):
        RobotiqModbusClient.Connect(GripperConfig(link="modbus_rtu",
                                                  serial_device="/nonexistent/ttyUSB7"))
    with pytest.raises(HardwareStationUnavailable,
                       match=r"no Robotiq gripper answered on .*slave 5.*slave_id and baud"):
        _client(server, slave_id=5, timeout=0.3, retries=0)


@pytest.mark.parametrize("gripper,message", [
    ({"link": "can"}, "gripper.link 'can' unknown; choose one of urcap_socket, modbus_rtu"),
    ({"link": "modbus_rtu", "baud": 12345}, "gripper.baud must be one of"),
    ({"link": "modbus_rtu", "slave_id": 0}, "gripper.slave_id must be a Modbus slave id"),
    ({"link": "modbus_rtu", "serial_device": " "}, "gripper.serial_device must name"),
    ({"retries": -1}, "gripper.retries must be >= 0"),
])
def test_bad_gripper_link_settings_are_one_line_errors(gripper, message):
    with pytest.raises(ValueError, match=message):
        ValidateHardwareConfig(HardwareConfig(gripper=GripperConfig(**gripper)))
    text = json.dumps({"hardware": {"gripper": gripper}})      # JSON is YAML
    with pytest.raises(ScenarioError, match=message) as err:
        LoadScenario(scenario_text=text)
    assert "\n" not in str(err.value) and "--scenario_text" in str(err.value)


def test_the_default_link_is_the_urcap_socket():
    g = GripperConfig()
    assert (g.link, g.baud, g.slave_id, g.serial_device) == ("urcap_socket", 115200, 9,
                                                              "/dev/ttyUSB0")
    ValidateHardwareConfig(HardwareConfig(gripper=GripperConfig(link="modbus_rtu")))


def test_the_station_picks_the_client_by_link(server):
    """``ConnectGripper`` (used by ``ConnectHardwareClients``): the URCap
    socket client by default, the Modbus RTU client for ``link: modbus_rtu``."""
    config = HardwareConfig()
    with FakeRobotiqServer() as socket_server:
        config.gripper = dc.replace(config.gripper, port=socket_server.port, host="127.0.0.1")
        client = ConnectGripper(config)
        assert type(client) is RobotiqClient
        client.Close()
    config.gripper = dc.replace(config.gripper, link="modbus_rtu", serial_device=server.device)
    client = ConnectGripper(config)
    assert type(client) is RobotiqModbusClient and client.Position() == 0
    assert server.received                       # it asked the Modbus slave
    client.Close()


def test_without_pymodbus_the_modbus_link_says_how_to_install(scenario, monkeypatch):
    monkeypatch.setitem(sys.modules, "pymodbus.client", None)
    s = dc.replace(scenario, hardware=HardwareConfig(gripper=GripperConfig(link="modbus_rtu")))
    with pytest.raises(HardwareStationUnavailable,
                       match=r"modbus_rtu needs pymodbus.*pip install -e \.\[hardware\]"):
        CheckHardwareSetup(s, own_clients=True)
