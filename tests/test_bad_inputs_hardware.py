"""Probes of issue 61 on the hardware side and the twin (defects 1, 2, 11,
17, 18, 22, 26): nothing can move before every check passed (the real
ur_rtde client against the UR controller EMULATOR, a FAKE Robotiq socket
server, the twin's camera server); every pose is a rigid transform
(scenario, calibration file, recording); the twin's servers listen on
loopback unless told otherwise; bad twin options, ports and robot
addresses are refused before anything is built or written.
"""
import json
import os
import random
import signal
import socket
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from lmap_drake.cli import main
from lmap_drake.config_checks import TransformError
from lmap_drake.errors import EXIT_BAD_INPUT
from lmap_drake.paths import DEFAULT_SCENARIO_FILE, REPO_ROOT
from lmap_drake.scenario import LoadScenario, ScenarioError
from lmap_drake.station.hardware_config import CalibrationError, LoadCameraCalibration

ZERO_AXIS = "!AngleAxis {angle_deg: 30, axis: [0, 0, 0]}"


def _run(capsys, *argv):
    code = main(list(argv))
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    return code, err


# ------------------------------------------------ 2. one rigid-transform check
@pytest.mark.parametrize("M, ok", [
    (np.eye(4), True),
    (np.diag([0.866, 0.866, 0.866, 1.0]), False),            # AngleAxis with a zero axis
    (np.diag([3.0, 3.0, 3.0, 1.0]), False),                  # scaled rotation
    (np.diag([1.0, 1.0, -1.0, 1.0]), False),                 # a reflection (det -1)
    (np.array([[1, 0, 0, np.nan], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]]), False),
    (np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1.0]]), False),
])
def test_transform_error_is_rigid_and_finite(M, ok):
    assert (TransformError(M) == "") == ok


@pytest.mark.parametrize("text, key", [
    ("{cameras: {camera0: {X_PB: {rotation: %s}}}}" % ZERO_AXIS, "cameras.camera0.X_PB"),
    ("{robot: {X_WB: {rotation: %s}}}" % ZERO_AXIS, "robot.X_WB"),
])
def test_non_rigid_scenario_pose_is_refused_naming_the_key(text, key):
    with pytest.raises(ScenarioError, match=rf"^{key} must be a rigid pose"):
        LoadScenario(scenario_text=text)


def test_non_rigid_calibration_is_refused_naming_the_file(tmp_path):
    f = tmp_path / "calib.yaml"
    f.write_text(f"X_WC:\n  translation: [0.5, -0.6, 0.47]\n  rotation: {ZERO_AXIS}\n")
    with pytest.raises(CalibrationError, match=f"{f}: X_WC must be a rigid pose"):
        LoadCameraCalibration(str(f))


def test_recording_with_a_scaled_rotation_is_refused(tmp_path, capsys):
    from lmap_drake.perception.recording import (CapturedView, LoadRecording, RecordingError,
                                                 SaveRecording)
    view = CapturedView(0, 0.3, 0.0, np.zeros((4, 5, 4), np.uint8),
                        np.ones((4, 5), np.float32), None, np.zeros(6), np.zeros(6),
                        np.array([0.085, 0.0, 0.0]))
    camera = {"width": 5, "height": 4, "fx": 5.0, "fy": 5.0, "cx": 2.5, "cy": 2.0}
    SaveRecording(tmp_path, [view], camera, np.eye(4), "hardware")
    LoadRecording(tmp_path)                                      # the rigid one loads
    manifest = tmp_path / "recording" / "recording.json"
    m = json.loads(manifest.read_text())
    X = np.eye(4)
    X[:3, :3] *= 3.0
    m["X_WC"] = X.tolist()
    manifest.write_text(json.dumps(m))
    with pytest.raises(RecordingError, match=f"{manifest}: X_WC must be a rigid pose"):
        LoadRecording(tmp_path)
    code, err = _run(capsys, "replay", str(tmp_path), "--output", str(tmp_path / "r"))
    assert code == EXIT_BAD_INPUT and "X_WC must be a rigid pose" in err
    assert not (tmp_path / "r").exists()


# ------------------------------------------------------ 18. robot_ip, segmenter
@pytest.mark.parametrize("ip", ["", "not an ip!", "999.1.1.1", "a..b"])
def test_bad_robot_ip_is_refused_at_load(capsys, tmp_path, ip):
    out = tmp_path / "o"
    code, err = _run(capsys, "run", "--hardware", "--dry-run", "--output", str(out),
                     "--scenario_text", "{hardware: {ur: {robot_ip: '%s'}}}" % ip)
    assert code == EXIT_BAD_INPUT and "hardware.ur.robot_ip" in err, err
    assert not out.exists()


@pytest.mark.parametrize("ip", ["192.168.1.102", "ur5.local", "::1", "localhost"])
def test_good_robot_addresses_load(ip):
    assert LoadScenario(scenario_text="{hardware: {ur: {robot_ip: '%s'}}}" % ip)


def test_label_segmenter_with_hardware_is_bad_input_before_any_output(capsys, tmp_path):
    out = tmp_path / "o"
    code, err = _run(capsys, "run", "--hardware", "--dry-run", "--output", str(out),
                     "--scenario_text", "{perception: {segmenter: label}}")
    assert code == EXIT_BAD_INPUT and "perception.segmenter" in err, err
    assert not out.exists()


# ------------------------------------------- 1. the pre-motion gate (emulator)
def _StartEmulator(q0):
    from lmap_drake.twin.ur_emulator import (DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORT,
                                             EmulatorProcess)
    for n in random.sample(range(20, 250), 8):
        host = f"127.0.0.{n}"
        free = True
        for port in (DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORT):
            with socket.socket() as s:
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                try:
                    s.bind((host, port))
                except OSError:
                    free = False
        if not free:
            continue
        try:
            return EmulatorProcess(host, q0=q0)
        except OSError as err:
            if "cannot bind" not in str(err):
                raise
    pytest.skip("UR emulator: UR's ports in use on every loopback address tried")


@pytest.fixture
def cell(tmp_path):
    """A UR controller EMULATOR (real ur_rtde client), a FAKE Robotiq socket
    server (gripper inactive: ACT 0) and the twin's camera server (serial
    ``twin``), all on loopback; yields (emulator, gripper server, overrides
    builder)."""
    from fakes.hardware import FakeRobotiqServer
    from lmap_drake.twin.camera_server import TwinCameraServer
    s = LoadScenario(filename=DEFAULT_SCENARIO_FILE)
    emu = _StartEmulator(s.robot.initial_q)
    info = {"width": 8, "height": 6, "fx": 8.0, "fy": 8.0, "cx": 4.0, "cy": 3.0,
            "serial": "twin", "depth_scale": float("nan"), "time_scale": 1.0}
    camera = TwinCameraServer(info, lambda: (0.0, np.zeros((6, 8, 4), np.uint8),
                                             np.ones((6, 8), np.float32))).Start()
    with FakeRobotiqServer() as gripper:
        def overrides(calibration, workspace_z=-0.2):
            return ("{hardware: {ur: {robot_ip: %s, workspace_min: [-0.85, -0.85, %g]}, "
                    "gripper: {host: 127.0.0.1, port: %d}, camera: {twin_address: "
                    "'127.0.0.1:%d', calibration_file: '%s'}}}" % (
                        emu.host, workspace_z, gripper.port, camera.port, calibration))
        yield emu, gripper, overrides
    camera.Close()
    emu.Close()


def _Calibration(tmp_path, serial):
    f = tmp_path / f"calib_{serial}.yaml"
    f.write_text("X_WC:\n  translation: [0.5, -0.6, 0.47]\n  rotation: !Rpy {deg: "
                 f"[-105, 0, 0]}}\ncamera_serial: {serial}\n")
    return f


def _NothingMoved(emu, gripper):
    assert emu.State()["programs"] == 0                       # no control script uploaded
    assert gripper.gripper.regs["ACT"] == 0                   # the gripper still inactive
    assert not [r for r in gripper.received if r.startswith("SET")], gripper.received


@pytest.mark.parametrize("case", ["other_camera", "start_pose_outside_workspace"])
def test_bad_calibration_or_start_pose_exits_2_before_anything_can_move(
        capsys, tmp_path, cell, case):
    emu, gripper, overrides = cell
    if case == "other_camera":
        text, match = overrides(_Calibration(tmp_path, "f1234567")), \
            "is for camera f1234567, the connected camera is twin"
    else:      # the default box floor (z 0.05 m) is above the start pose's wrists
        text, match = overrides(_Calibration(tmp_path, "twin"), 0.05), \
            "hardware.ur.workspace_min/max do not hold the arm where it stands"
    out = tmp_path / "o"
    code, err = _run(capsys, "run", "--hardware", "--no-confirm", "--output", str(out),
                     "--scenario_text", text)
    assert code == EXIT_BAD_INPUT and match in err, err
    _NothingMoved(emu, gripper)
    assert not (out / "episode.json").exists()


def test_the_gate_enables_motion_only_after_its_checks(tmp_path, cell):
    """The control: with a good calibration the gate does upload the control
    script and activate the gripper (so the test above could fail)."""
    from lmap_drake.station.hardware.station import OpenCheckedHardware
    emu, gripper, overrides = cell
    s = LoadScenario(filename=DEFAULT_SCENARIO_FILE,
                     scenario_text=overrides(_Calibration(tmp_path, "twin")))
    clients, X_WC, own = OpenCheckedHardware(s, read_only=True)
    _NothingMoved(emu, gripper)                                   # read-only: nothing
    clients.Close()
    clients, X_WC, own = OpenCheckedHardware(s)
    try:
        assert own and np.allclose(X_WC.translation(), [0.5, -0.6, 0.47])
        assert emu.State()["programs"] >= 1 and gripper.gripper.regs["ACT"] == 1
    finally:
        clients.Close()


# ------------------------------------------------- 11, 17, 22: twin options
@pytest.mark.parametrize("argv, match", [
    (["--camera_port", "70000"], "--camera_port must be a TCP port in 1..65535"),
    (["--gripper_port", "0"], "--gripper_port must be a TCP port in 1..65535"),
    (["--host", "0.0.0.0"], "not a loopback address"),
    (["--host", "192.168.1.5"], "pass --allow_remote"),
    (["--duration", "nan"], "--duration must be a finite number >= 0"),
    (["--fault_after_grasp_move", "-1"], "--fault_after_grasp_move must be a finite number"),
])
def test_twin_bad_options_exit_2_without_an_output_folder(capsys, tmp_path, argv, match):
    out = tmp_path / "twin"
    code, err = _run(capsys, "twin", "--output", str(out), *argv)
    assert code == EXIT_BAD_INPUT and match in err, err
    assert not out.exists()


def test_servers_that_control_a_robot_listen_on_loopback_unless_allowed():
    from fakes.hardware import FakeGripper
    from lmap_drake.twin.camera_server import TwinCameraServer
    from lmap_drake.twin.listen import ListenError, ListenHostWarning
    from lmap_drake.twin.robotiq_server import RobotiqSocketServer
    from lmap_drake.twin.ur_emulator import EmulatorProcess, UrEmulator
    for make in (lambda: UrEmulator("0.0.0.0"), lambda: EmulatorProcess("0.0.0.0"),
                 lambda: RobotiqSocketServer(FakeGripper(), "0.0.0.0"),
                 lambda: TwinCameraServer({}, None, "0.0.0.0")):
        with pytest.raises(ListenError, match="--allow_remote"):
            make()
    assert ListenHostWarning("127.0.0.7") == "" and ListenHostWarning("::1") == ""
    assert "warning" in ListenHostWarning("0.0.0.0", allow_remote=True)


@pytest.mark.parametrize("argv, match", [
    (["--host", "0.0.0.0"], "not a loopback address"),
    (["--rtde-port", "70000"], "--rtde-port must be a TCP port in 1..65535"),
])
def test_ur_emulator_cli_refuses_remote_host_and_bad_port(capsys, argv, match):
    from lmap_drake.twin.ur_emulator import main as emulator_main
    with pytest.raises(SystemExit) as exc:
        emulator_main(argv)
    assert exc.value.code == EXIT_BAD_INPUT and match in capsys.readouterr().err


# ------------------------------------------------------- 26: twin leftovers
def test_twin_gripper_refuses_out_of_range_registers():
    from lmap_drake.station.hardware_config import GripperConfig
    from lmap_drake.twin.robotiq_server import RobotiqSocketServer
    from lmap_drake.twin.gripper import TwinGripper
    g = TwinGripper(GripperConfig(), 0.085)
    with RobotiqSocketServer(g) as server, socket.create_connection(
            ("127.0.0.1", server.port), timeout=5) as s:
        f = s.makefile("rwb")
        for line, reply in (("SET POS 999999", "?"), ("SET POS -1", "?"), ("SET SPE 256", "?"),
                            ("SET POS 255", "ack")):
            f.write((line + "\n").encode())
            f.flush()
            assert s.recv(64).decode().strip() == reply, line
    assert g.Get("PRE") == 255


def test_killed_twin_leaves_no_emulator_log_in_the_system_temp(tmp_path):
    """The twin's UR emulator logs into the twin's output folder (given as
    ``TwinOptions.log_dir``); a SIGKILLed twin leaves nothing in the system
    temp folder (TMPDIR private to the child here)."""
    sys_tmp, out = tmp_path / "sys_tmp", tmp_path / "out"
    sys_tmp.mkdir()
    out.mkdir()
    code = textwrap.dedent(f"""
        import random, sys
        from lmap_drake.twin.twin import _EmulatorChild
        for n in random.sample(range(20, 250), 8):
            try:
                child = _EmulatorChild(f"127.0.0.{{n}}", [0.0, -1.5, 1.5, -1.57, -1.57, 0.0],
                                       {str(out / 'ur_emulator.log')!r})
                break
            except OSError:
                continue
        print("ready", flush=True)
        sys.stdin.read()
    """)
    env = dict(os.environ, TMPDIR=str(sys_tmp), PYTHONPATH=str(REPO_ROOT))
    p = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE,
                         stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert p.stdout.readline().strip() == "ready"
    finally:
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=10)
    time.sleep(0.5)        # the emulator child sees its stdin close and exits
    assert (out / "ur_emulator.log").exists()
    assert not list(sys_tmp.glob("ur_emulator_*")), list(sys_tmp.iterdir())
