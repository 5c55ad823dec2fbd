"""The hardware station built on FAKE clients (fake ur_rtde interfaces, a
FakeRobotiqServer on localhost speaking the URCap protocol, a fake
pyrealsense2 module; see tests/fakes/hardware.py). Nothing here
talks to a robot: these tests check the Drake wiring, the port contract,
the safety paths, not the devices. The whole hardware episode on these
fakes (plan-only, confirmation, aborts) is tested in tests/test_episode_hardware.py."""
import sys

import numpy as np
import pytest
from pydrake.common.value import AbstractValue
from pydrake.geometry import RenderLabel
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, PortDataType
from pydrake.systems.primitives import ConstantVectorSource

from lmap_drake.cli import main
from lmap_drake.paths import DEFAULT_SCENARIO_FILE
from lmap_drake.scenario import LoadScenario
from lmap_drake.station import STATION_PORTS, MakeStation
from fakes.hardware import FakeRobotiqServer, MakeFakeHardwareClients
from lmap_drake.station.hardware.safety import (HardwareAbort, JointLimitRefusal,
                                                VelocityLimitRefusal)
from lmap_drake.station.hardware.station import (HardwareCamera, MakeHardwareStation,
                                                 StopHardwareStation)
from lmap_drake.station.hardware.robotiq_client import GripperCommandRefusal
from lmap_drake.station.hardware_config import (CalibrationError, CalibrationX_WC,
                                                LoadCameraCalibration)
from lmap_drake.errors import HardwareStationUnavailable

CALIB = "diagrams/calibration_example.yaml"


@pytest.fixture
def hw_scenario(scenario):
    scenario.hardware.camera.calibration_file = CALIB
    scenario.simulator_config.target_realtime_rate = 0.0
    # A pedestal cell: the default start pose has its wrists 8 cm below the
    # robot base plane, which the every-link workspace check would refuse.
    scenario.hardware.ur.workspace_min = [-0.85, -0.85, -0.2]
    return scenario


@pytest.fixture
def gripper_server():
    with FakeRobotiqServer() as s:  # fake URCap peer on localhost
        yield s


@pytest.fixture
def fake_station(hw_scenario, gripper_server):
    clients = MakeFakeHardwareClients(hw_scenario.hardware, q0=hw_scenario.robot.initial_q,
                                      gripper_server=gripper_server)
    station = MakeHardwareStation(hw_scenario, clients)
    yield station, clients
    StopHardwareStation(station)


def _describe(system):
    """name -> (kind, size or value type) for every input and output port."""
    out = {}
    for ports in ([system.get_input_port(i) for i in range(system.num_input_ports())],
                  [system.get_output_port(i) for i in range(system.num_output_ports())]):
        for p in ports:
            if p.get_data_type() == PortDataType.kVectorValued:
                out[p.get_name()] = ("vector", p.size())
            else:
                out[p.get_name()] = ("abstract", None)
    return out


def test_contract_same_port_names_sizes_and_types_as_simulation(fake_station, hw_scenario):
    station, _ = fake_station
    sim = MakeStation(hw_scenario)
    assert _describe(station) == _describe(sim)
    assert sorted(_describe(station)) == sorted(STATION_PORTS["inputs"] + STATION_PORTS["outputs"])
    hw_ctx, sim_ctx = station.CreateDefaultContext(), sim.CreateDefaultContext()
    for name in ("camera0.rgb_image", "camera0.depth_image", "camera0.label_image"):
        a = station.GetOutputPort(name).Eval(hw_ctx)
        b = sim.GetOutputPort(name).Eval(sim_ctx)
        assert type(a) is type(b), name
        assert a.data.shape == b.data.shape and a.data.dtype == b.data.dtype, name


def test_outputs_carry_device_readings(fake_station, hw_scenario):
    station, clients = fake_station
    ctx = station.CreateDefaultContext()
    assert np.allclose(station.GetOutputPort("ur5.position_measured").Eval(ctx),
                       hw_scenario.robot.initial_q)
    assert station.GetOutputPort("ur5.state_estimated").Eval(ctx).shape == (12,)
    grip = station.GetOutputPort("gripper.state_measured").Eval(ctx)
    assert grip[0] == pytest.approx(0.085)  # fake gripper starts at POS 0 = open
    depth = station.GetOutputPort("camera0.depth_image").Eval(ctx).data[..., 0]
    assert depth[240, 320] == pytest.approx(0.6, abs=1e-6)
    label = station.GetOutputPort("camera0.label_image").Eval(ctx).data
    assert (label == int(RenderLabel.kEmpty)).all()  # no labels on hardware
    X_WC, info = HardwareCamera(station)
    assert X_WC.IsNearlyEqualTo(LoadCameraCalibration(CALIB).X_WC.GetDeterministicValue(), 1e-12)
    assert info.width() == 640 and info.focal_x() == pytest.approx(0.713 * 640)


def _run(station, q_cmd, opening, t_end):
    builder = DiagramBuilder()
    builder.AddSystem(station)
    q_src = builder.AddSystem(ConstantVectorSource(np.asarray(q_cmd, float)))
    g_src = builder.AddSystem(ConstantVectorSource([opening]))
    builder.Connect(q_src.get_output_port(), station.GetInputPort("ur5.position"))
    builder.Connect(g_src.get_output_port(), station.GetInputPort("gripper.position"))
    sim = Simulator(builder.Build())
    sim.set_target_realtime_rate(1.0)  # as on hardware: events stand for wall time
    sim.AdvanceTo(t_end)
    return sim


def test_wrist_force_is_the_arms_tcp_force_estimate(fake_station, hw_scenario):
    station, clients = fake_station
    clients.ur.receive.tcp_force = np.array([1.5, -2.0, 3.25, 0.1, 0.2, 0.3])
    sim = _run(station, hw_scenario.robot.initial_q, 0.085, 0.05)
    f = station.GetOutputPort("ur5.wrist_force").Eval(
        station.GetMyContextFromRoot(sim.get_context()))
    assert np.allclose(f, [1.5, -2.0, 3.25])      # the force part, as read


def test_commands_reach_the_fake_devices(fake_station, hw_scenario, gripper_server):
    station, clients = fake_station
    q_cmd = np.array(hw_scenario.robot.initial_q) + [0.003, 0, 0, 0, 0, 0]
    sim = _run(station, q_cmd, 0.0, 0.2)
    assert np.allclose(clients.ur.last_target, q_cmd)
    assert any(line.startswith("SET POS 255 SPE 255 FOR 50 GTO 1")
               for line in gripper_server.received)
    n_pos = sum(line.startswith("SET POS") for line in gripper_server.received)
    assert n_pos == 1  # sent once, not at every update
    assert np.allclose(clients.ur.receive.q, q_cmd, atol=1e-6)
    assert np.allclose(station.GetOutputPort("ur5.position_measured").Eval(
        station.GetMyContextFromRoot(sim.get_context())), q_cmd, atol=1e-6)


def test_refused_joint_command_aborts_the_episode(fake_station, hw_scenario):
    station, clients = fake_station
    q = np.array(hw_scenario.robot.initial_q)
    q[2] = 3.3
    with pytest.raises(JointLimitRefusal, match="elbow_joint"):
        _run(station, q, 0.085, 0.1)
    assert clients.ur.control.servoj_calls == []
    assert clients.ur.control.script_stops == 1


def test_jump_is_refused_as_too_fast(fake_station, hw_scenario):
    station, clients = fake_station
    with pytest.raises(VelocityLimitRefusal):
        _run(station, np.array(hw_scenario.robot.initial_q) + 0.1, 0.085, 0.1)
    assert clients.ur.control.servoj_calls == []


def test_bad_gripper_command_is_refused(fake_station, hw_scenario, gripper_server):
    station, _ = fake_station
    with pytest.raises(GripperCommandRefusal):
        _run(station, hw_scenario.robot.initial_q, 0.2, 0.1)
    assert not any(line.startswith("SET POS") for line in gripper_server.received)


def test_protective_stop_aborts_simulation_with_clear_message(fake_station, hw_scenario):
    station, clients = fake_station
    clients.ur.receive.protective_stopped = True
    with pytest.raises(HardwareAbort, match="hardware episode aborted: the UR5 is protective "
                                            "stopped.*the arm was stopped"):
        _run(station, hw_scenario.robot.initial_q, 0.085, 0.1)
    assert clients.ur.control.script_stops == 1


def test_lost_gripper_link_aborts_and_stops_the_arm(fake_station, hw_scenario, gripper_server):
    station, clients = fake_station
    gripper_server.DropClients()
    with pytest.raises(HardwareAbort, match="gripper"):
        _run(station, hw_scenario.robot.initial_q, 0.085, 0.2)
    assert clients.ur.control.script_stops == 1 and not clients.ur.streaming


def test_calibration_in_robot_base_frame_is_moved_to_world(tmp_path, hw_scenario):
    f = tmp_path / "calib.yaml"
    f.write_text("X_WC:\n  base_frame: robot_base\n  translation: [0.1, 0.2, 0.3]\n"
                 "  rotation: !Rpy { deg: [-90.0, 0.0, 0.0] }\ncamera_serial: f0000001\n")
    calib = LoadCameraCalibration(str(f))
    X_WB = RigidTransform(RollPitchYaw(0, 0, np.pi), [0.0, 0.0, 0.0])
    X_WC = CalibrationX_WC(calib, X_WB)
    assert np.allclose(X_WC.translation(), [-0.1, -0.2, 0.3])


def test_calibration_for_another_camera_is_refused(tmp_path, hw_scenario, gripper_server):
    f = tmp_path / "calib.yaml"
    f.write_text("X_WC:\n  translation: [0.5, -0.6, 0.47]\ncamera_serial: f7777777\n")
    hw_scenario.hardware.camera.calibration_file = str(f)
    clients = MakeFakeHardwareClients(hw_scenario.hardware, q0=hw_scenario.robot.initial_q,
                                      gripper_server=gripper_server)
    with pytest.raises(CalibrationError, match="for camera f7777777.*f0000001"):
        MakeHardwareStation(hw_scenario, clients)
    clients.Close()


def test_missing_calibration_is_a_clear_error(hw_scenario, gripper_server):
    hw_scenario.hardware.camera.calibration_file = ""
    with pytest.raises(CalibrationError, match="calibration_file is empty"):
        MakeHardwareStation(hw_scenario, clients=object())


def test_make_station_without_libraries_says_how_to_install(scenario, monkeypatch):
    # Without ur_rtde (the test extra installs it: hide it), the error names the
    # hardware station and the extra.
    monkeypatch.setitem(sys.modules, "rtde_control", None)
    with pytest.raises(HardwareStationUnavailable,
                       match=r"hardware station needs ur_rtde.*pip install -e \.\[hardware\]"):
        MakeStation(scenario, hardware=True)


def test_cli_dry_run_needs_hardware(tmp_path, capsys):
    assert main(["run", "--dry-run", "--output", str(tmp_path)]) == 2
    assert "--dry-run needs --hardware (in simulation use --plan-only)" in \
        capsys.readouterr().err


def test_cli_hardware_dry_run_without_libraries_fails_clearly(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)   # never reach a device
    assert main(["run", "--hardware", "--dry-run", "--output", str(tmp_path)]) == 1
    assert "pip install -e .[hardware]" in capsys.readouterr().err


def test_one_of_everything_hardware_block_loads():
    s = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="OneOfEverything")
    assert s.hardware.ur.robot_ip == "192.168.1.110"
    assert s.hardware.gripper.pos_closed == 228
    assert s.hardware.camera.depth_width == 1024
