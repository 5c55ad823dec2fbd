"""``MakeHardwareStation``: the real UR5 cell as a Diagram with the same
exported ports as the simulated station (``lmap_drake.station.STATION_PORTS``).

- ``ur5.position`` (in, 6 rad) -> safety checks -> ur_rtde servoJ streaming;
- ``gripper.position`` (in, 1 m) -> Robotiq ``SET POS .. SPE .. FOR .. GTO 1``
  (``hardware.gripper.link`` urcap_socket) or the same request written to
  the 2F-85's Modbus RTU registers from 0x03E8 (modbus_rtu);
- ``ur5.position_measured`` (6), ``ur5.state_estimated`` (12) <- getActualQ/Qd;
- ``ur5.wrist_force`` (3, N, base frame) <- getActualTCPForce (its force part);
- ``gripper.state_measured`` (3) <- ``GET POS``, ``GET OBJ`` (opening m,
  rate m/s, 1 when the gripper reports it stopped on an object while
  closing, else 0);
- ``camera0.rgb_image`` / ``camera0.depth_image`` <- RealSense, depth aligned
  to colour, metres, +inf where the camera has no return;
- ``camera0.label_image``: same type and size as in simulation, but every
  pixel is ``RenderLabel.kEmpty`` (decodes to background): a real camera has
  no ground-truth labels, so a pipeline on hardware must use a segmenter that
  does not read labels (``perception.segmenter`` other than ``label``).

The camera pose comes from ``hardware.camera.calibration_file``, the
intrinsics from the device: ``HardwareCamera(station)`` returns them.
Devices are opened through the pre-motion gate ``OpenCheckedHardware``:
every check (scenario, calibration, camera serial, start pose) before
``EnableMotion`` (control script upload, gripper activation).
Call ``StopHardwareStation(station)`` when done (also registered with
``atexit``): it stops the servo, the control script, the gripper socket and
the camera pipeline.
"""
from __future__ import annotations

import atexit
import dataclasses as dc

import numpy as np

from pydrake.systems.framework import Diagram, DiagramBuilder

from lmap_drake.errors import ConfigError, HardwareStationUnavailable
from lmap_drake.scenario import Scenario
from lmap_drake.station.hardware.realsense_client import ConnectRealSense, ImportPyrealsense2
from lmap_drake.station.hardware.robotiq_client import RobotiqClient
from lmap_drake.station.hardware.robotiq_modbus_client import ImportPymodbus, RobotiqModbusClient
from lmap_drake.station.hardware.safety import SafetyChecker, SafetyRefusal
from lmap_drake.station.hardware.systems import RealSenseCamera, RobotiqDriver, Ur5Driver
from lmap_drake.station.hardware.twin_camera_client import TwinCameraClient
from lmap_drake.station.hardware.ur_client import ConnectUr, ImportUrRtde
from lmap_drake.station.hardware_config import (CalibrationError, CalibrationX_WC,
                                                CheckCalibrationSerial,
                                                HardwareConfig, LoadCameraCalibration,
                                                UrConfig, ValidateHardwareConfig)


@dc.dataclass
class HardwareClients:
    """The three device clients (real or injected fakes with the same
    methods). ``Close`` stops and disconnects all of them, arm first."""
    ur: object
    gripper: object
    camera: object

    def Close(self) -> None:
        for client in (self.ur, self.gripper, self.camera):
            if client is None:
                continue
            try:
                client.Close()
            except Exception:
                pass


def _Unavailable(msg: str) -> Exception:
    return HardwareStationUnavailable(msg)


def ConnectGripper(config: HardwareConfig):
    """The gripper client ``hardware.gripper.link`` names: the URCap socket
    (``RobotiqClient``) or Modbus RTU (``RobotiqModbusClient``)."""
    if config.gripper.link == "modbus_rtu":
        return RobotiqModbusClient.Connect(config.gripper)
    return RobotiqClient.Connect(config.gripper, config.gripper.host or config.ur.robot_ip)


def ConnectHardwareClients(config: HardwareConfig, read_only: bool = False) -> HardwareClients:
    """Connects UR5, gripper and camera (libraries checked first). Nothing
    sent here can move anything: the RTDE receive interface only, the
    gripper's socket without activation, the camera. Unless ``read_only``,
    ``EnableMotion`` follows (``OpenCheckedHardware`` runs its checks in
    between)."""
    ImportUrRtde()
    if config.gripper.link == "modbus_rtu":
        ImportPymodbus()
    if not config.camera.twin_address:
        ImportPyrealsense2()
    ur = gripper = camera = None
    try:
        ur = ConnectUr(config.ur, read_only=True)
        gripper = ConnectGripper(config)
        if config.camera.twin_address:     # a digital twin's frames (lmap-drake twin)
            camera = TwinCameraClient(config.camera.twin_address, config.camera.frame_timeout)
        else:
            camera = ConnectRealSense(config.camera)
        if not read_only:
            EnableMotion(HardwareClients(ur, gripper, camera), config)
    except BaseException:
        HardwareClients(ur, gripper, camera).Close()
        raise
    return HardwareClients(ur, gripper, camera)


def EnableMotion(clients: HardwareClients, config: HardwareConfig) -> None:
    """The first bytes that can move anything: ur_rtde's control script
    upload (RTDE control interface) and the gripper's activation (an
    inactive 2F-85 strokes its fingers to calibrate)."""
    clients.ur.OpenControl()
    if config.gripper.activate:
        clients.gripper.Activate(timeout=config.gripper.activation_timeout)


class StartPoseError(ConfigError):
    """The arm stands where the safety checks refuse every command (outside
    its joint limits or ``hardware.ur.workspace_min/max``): bad input."""


def CheckStartPose(q, config: UrConfig) -> None:
    """Refuses a measured start pose that the safety checks would refuse
    (joint limits, every link in the workspace box): raises StartPoseError."""
    checker = SafetyChecker(config)
    try:
        checker.CheckJointLimits(q)
        checker.CheckWorkspace(q)
    except SafetyRefusal as err:
        raise StartPoseError(
            "hardware.ur.workspace_min/max",
            f"do not hold the arm where it stands (q = {np.round(q, 4).tolist()} rad), so "
            f"every command would be refused: {str(err).replace('refused UR5 command: ', '')}"
            f"; move the arm or change the box") from None


def CheckHardwareSetup(scenario: Scenario, own_clients: bool):
    """Checks before touching any device: the client libraries (when we
    connect ourselves), the hardware config and the calibration file.
    Returns (calibration, X_WC). Raises HardwareStationUnavailable, or
    CalibrationError (bad input)."""
    config = scenario.hardware
    if own_clients:  # a missing library is the first thing to report
        ImportUrRtde()
        if config.gripper.link == "modbus_rtu":
            ImportPymodbus()
        if not config.camera.twin_address:
            ImportPyrealsense2()
    try:
        ValidateHardwareConfig(config)
    except ValueError as err:
        raise HardwareStationUnavailable(f"hardware station: {err}") from err
    calib = LoadCameraCalibration(config.camera.calibration_file)   # CalibrationError: bad input
    return calib, CalibrationX_WC(calib, scenario.robot.X_WB.GetDeterministicValue())


def CheckHardwareScenario(scenario: Scenario, own_clients: bool = True):
    """The checks of ``OpenCheckedHardware`` that need no device (``lmap-drake
    run --hardware`` runs them before it makes its output folder): the
    segmenter, the client libraries (when we connect ourselves), the
    ``hardware`` config and the calibration file. Returns (calibration,
    X_WC). Raises ConfigError / CalibrationError (bad input) or
    HardwareStationUnavailable."""
    if scenario.perception.segmenter == "label":
        raise ConfigError("perception.segmenter",
                          "'label' reads simulator labels, which a real camera does not have; "
                          "use segnet (the default) or color_depth with --hardware")
    return CheckHardwareSetup(scenario, own_clients)


def OpenCheckedHardware(scenario: Scenario, clients: HardwareClients | None = None,
                        read_only: bool = False, progress=None):
    """The pre-motion gate. Every check runs before the first byte that can
    move anything: ``CheckHardwareScenario``; then (connecting read-only
    unless ``clients`` are given) the calibration's camera serial against
    the connected camera and the measured start pose (``CheckStartPose``);
    only then ``EnableMotion`` (not with ``read_only``). Returns (clients,
    calibration X_WC, whether we connected them); on any error the clients
    we connected are closed."""
    config = scenario.hardware
    own = clients is None
    calib, X_WC = CheckHardwareScenario(scenario, own)
    if own:
        if progress is not None:
            progress(f"connecting to the UR5 at {config.ur.robot_ip} (read-only until every "
                     f"check passed" + (": nothing can move)" if read_only else ")"))
        clients = ConnectHardwareClients(config, read_only=True)
    try:
        CheckCalibrationSerial(calib, str(getattr(clients.camera, "serial", "")),
                               config.camera.calibration_file)
        q, _ = clients.ur.ReadState()
        CheckStartPose(q, config.ur)
        if own and not read_only:
            EnableMotion(clients, config)
    except BaseException:
        if own:
            clients.Close()
        raise
    return clients, X_WC, own


def MakeHardwareStation(scenario: Scenario, clients: HardwareClients | None = None,
                        read_only: bool = False) -> Diagram:
    """The hardware station Diagram for ``scenario.hardware``. ``clients``
    (tests, or a caller that connected first) are used as given; otherwise
    the real devices are connected (read-only with ``read_only``). With
    ``read_only`` the station only reads: no joint or gripper command is
    sent whatever its inputs say. Goes through ``OpenCheckedHardware``.
    Raises HardwareStationUnavailable when a library or a device is missing,
    CalibrationError / ConfigError (bad input) for a bad calibration file,
    one made for another camera, or a start pose outside the limits."""
    config = scenario.hardware
    clients, X_WC, own_clients = OpenCheckedHardware(scenario, clients, read_only)
    try:
        builder = DiagramBuilder()
        ur5 = builder.AddNamedSystem("ur5_driver", Ur5Driver(
            clients.ur, config.ur.command_period, command=not read_only))
        gripper = builder.AddNamedSystem(
            "gripper_driver", RobotiqDriver(clients.gripper, config.gripper.update_period,
                                            on_abort=clients.ur.Halt, command=not read_only))
        camera = builder.AddNamedSystem(
            "camera0", RealSenseCamera(clients.camera, 1.0 / config.camera.fps, X_WC,
                                       on_abort=clients.ur.Halt))
        builder.ExportInput(ur5.GetInputPort("position"), "ur5.position")
        builder.ExportInput(gripper.GetInputPort("position"), "gripper.position")
        builder.ExportOutput(ur5.GetOutputPort("position_measured"), "ur5.position_measured")
        builder.ExportOutput(ur5.GetOutputPort("state_estimated"), "ur5.state_estimated")
        builder.ExportOutput(ur5.GetOutputPort("wrist_force"), "ur5.wrist_force")
        builder.ExportOutput(gripper.GetOutputPort("state_measured"), "gripper.state_measured")
        builder.ExportOutput(camera.GetOutputPort("rgb_image"), "camera0.rgb_image")
        builder.ExportOutput(camera.GetOutputPort("depth_image"), "camera0.depth_image")
        builder.ExportOutput(camera.GetOutputPort("label_image"), "camera0.label_image")
        diagram = builder.Build()
        diagram.set_name("station")
    except BaseException:
        if own_clients:
            clients.Close()
        raise
    atexit.register(clients.Close)
    return diagram


def _Drivers(station: Diagram):
    return [station.GetSubsystemByName(n) for n in ("ur5_driver", "gripper_driver", "camera0")]


def StopHardwareStation(station: Diagram) -> None:
    """Stops the arm (servoStop, stopScript) and closes every client."""
    ur5, gripper, camera = _Drivers(station)
    HardwareClients(ur5.client, gripper.client, camera.client).Close()


def HardwareCamera(station: Diagram):
    """(X_WC RigidTransform, CameraInfo) of camera0 on the hardware station."""
    camera = station.GetSubsystemByName("camera0")
    return camera.X_WC, camera.camera_info
