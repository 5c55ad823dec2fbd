"""Configuration of the hardware station (UR5 over ur_rtde, Robotiq 2F-85
over the URCap socket or Modbus RTU, RealSense L515 over pyrealsense2).

These dataclasses are the ``hardware:`` section of a scenario; they are
loaded with Drake's ``yaml_load_typed`` like the rest of the scenario, so
unknown keys are errors. Units: metres, seconds, radians; the gripper's
speed and force are the Robotiq register units 0..255 (not SI).

The camera pose comes from a separate calibration file (see
``CameraCalibration`` and ``diagrams/calibration_example.yaml``), so that a
re-calibration does not touch the scenario.
"""

import dataclasses as dc
import ipaddress
import re
from pathlib import Path

import numpy as np
from pydrake.common.schema import Transform
from pydrake.common.yaml import yaml_load_typed
from pydrake.math import RigidTransform

from lmap_drake.config_checks import TransformError
from lmap_drake.errors import InputError
from lmap_drake.paths import REPO_ROOT


@dc.dataclass
class UrConfig:
    """UR5 over ur_rtde (RTDEControlInterface + RTDEReceiveInterface).

    ``servo_lookahead_time`` (s, UR range 0.03..0.2) and ``servo_gain`` (UR
    range 100..2000) are servoJ's smoothing and proportional gain.
    ``joint_speed_limit`` (rad/s, at most pi, the UR5 joint limit) bounds
    every commanded joint motion; commands faster than it are refused, and
    the streaming thread additionally never moves its servo target faster
    than it. ``joint_acceleration_limit`` (rad/s^2) is passed to servoJ
    (which, per the ur_rtde docs, ignores speed and acceleration);
    ``servoStop`` decelerates at twice it. The workspace box bounds the TCP
    position (2F-85 ``tcp`` frame, between the pads) in the robot base frame
    (the UR controller's "Base" frame = the DH base frame of
    ``lmap_drake.robot``), metres. ``command_period`` is the period
    (s) of the Drake-side update that reads the arm state and takes a new
    command; the streaming thread interpolates between commands at
    ``rtde_frequency``.
    """
    robot_ip: str = "192.168.1.102"  # the UR controller's address (RTDE; the gripper's too)
    rtde_frequency: float = 500.0  # Hz, RTDE rate; the streaming thread's servoJ rate, (0, 500]
    servo_lookahead_time: float = 0.1
    servo_gain: float = 300.0
    joint_speed_limit: float = 0.5
    joint_acceleration_limit: float = 1.0
    # Lower corner [x, y, z] (m, base frame B) of the box that the TCP, the
    # elbow, the wrists and the flange must stay in; commands leaving it are refused.
    workspace_min: list[float] = dc.field(default_factory=lambda: [-0.85, -0.85, 0.05])
    # Upper corner [x, y, z] (m, base frame B) of that workspace box.
    workspace_max: list[float] = dc.field(default_factory=lambda: [0.85, 0.85, 0.95])
    command_period: float = 0.01


GRIPPER_LINKS = ("urcap_socket", "modbus_rtu")
MODBUS_BAUDS = (9600, 19200, 38400, 57600, 115200)


@dc.dataclass
class GripperConfig:
    """Robotiq 2F-85, reached as ``link`` says: ``urcap_socket``, the
    Robotiq URCap's ASCII socket (port 63352 on the UR controller; ``host``
    empty means ``ur.robot_ip``), or ``modbus_rtu``, Modbus RTU over RS-485
    (a USB adapter or the UR tool connector) on ``serial_device`` at
    ``baud``, 8 data bits, no parity, 1 stop bit, slave ``slave_id``.
    ``speed`` and ``force`` are register values 0..255 (255 = fastest /
    strongest; 50 is a gentle grip for a leaf). ``pos_open`` /
    ``pos_closed`` are the POS register values taken as 85 mm and 0 mm;
    opening is linear in between (an approximation of the linkage).
    ``timeout`` (s) bounds every reply (socket line or Modbus frame);
    ``activation_timeout`` (s) the activation."""
    link: str = "urcap_socket"  # urcap_socket (URCap socket on the UR controller) or modbus_rtu (RS-485)
    host: str = ""
    port: int = 63352  # TCP port of the Robotiq URCap's socket on the UR controller
    speed: int = 255
    force: int = 50
    pos_open: int = 0
    pos_closed: int = 255
    timeout: float = 2.0
    activation_timeout: float = 10.0  # s: the gripper must report itself active (STA 3) within this
    serial_device: str = "/dev/ttyUSB0"  # modbus_rtu: the RS-485 serial device (e.g. /dev/serial/by-id/...)
    baud: int = 115200  # modbus_rtu: bits per second (the 2F-85's factory setting is 115200)
    slave_id: int = 9  # modbus_rtu: the gripper's Modbus slave id (factory setting 9)
    retries: int = 1  # modbus_rtu: a request without a reply within timeout is sent again this often
    activate: bool = True  # activate the gripper on connect if inactive (it opens and closes once)
    update_period: float = 0.05  # s, period of the driver that reads and commands the gripper


@dc.dataclass
class RealSenseConfig:
    """RealSense L515 through pyrealsense2 (<= 2.54, the last with L515
    support). ``serial`` empty means the first device found. Colour is
    ``width`` x ``height`` (the size of the station's images: depth is
    aligned to colour); depth streams at ``depth_width`` x ``depth_height``.
    ``calibration_file`` is a YAML file with the camera pose (see
    ``CameraCalibration``); a relative path is tried from the current folder,
    then from the repository root. ``twin_address`` ("host:port"): read the
    frames of a digital twin (``lmap-drake twin``) instead of a RealSense."""
    serial: str = ""
    width: int = 640
    height: int = 480
    depth_width: int = 640
    depth_height: int = 480
    fps: int = 30  # frames per second of both streams; the station's camera samples at this rate
    frame_timeout: float = 5.0  # s: no frameset within this aborts the hardware episode
    calibration_file: str = ""
    twin_address: str = ""


@dc.dataclass
class HardwareConfig:
    """The ``hardware:`` section of a scenario (used with ``--hardware``)."""
    ur: UrConfig = dc.field(default_factory=UrConfig)
    gripper: GripperConfig = dc.field(default_factory=GripperConfig)
    camera: RealSenseConfig = dc.field(default_factory=RealSenseConfig)


@dc.dataclass
class CameraCalibration:
    """Contents of a calibration file: the pose of the colour camera's
    optical frame C (Drake camera convention: +z forward, +x right, +y down).

    ``X_WC.base_frame`` is ``world`` (pose in the scenario's world frame) or
    ``robot_base`` (pose in the UR base frame, as hand-eye calibration tools
    report it; the station turns it into world with ``robot.X_WB``).
    ``camera_serial``, when not empty, must match the connected camera.
    Rotation as Drake's schema ``!Rpy {deg: [r, p, y]}`` (or any other
    ``pydrake.common.schema.Rotation`` form)."""
    X_WC: Transform = dc.field(default_factory=Transform)
    camera_serial: str = ""
    notes: str = ""


class CalibrationError(InputError, ValueError):
    """The calibration file is missing or malformed."""


def ResolveConfigPath(filename: str) -> Path:
    """``filename`` as given if it exists, else relative to the repository."""
    path = Path(filename)
    if path.is_absolute() or path.exists():
        return path
    return REPO_ROOT / path


def LoadCameraCalibration(filename: str) -> CameraCalibration:
    """Loads a calibration file; raises CalibrationError with the path."""
    if not filename:
        raise CalibrationError(
            "hardware.camera.calibration_file is empty: the hardware station needs the "
            "camera pose X_WC from a calibration file (format: "
            "diagrams/calibration_example.yaml)")
    path = ResolveConfigPath(filename)
    if not path.exists():
        raise CalibrationError(f"camera calibration file not found: {path}")
    if not path.is_file():
        raise CalibrationError(f"camera calibration file {path} is not a file")
    try:
        calib = yaml_load_typed(schema=CameraCalibration, filename=str(path),
                                defaults=CameraCalibration())
    except Exception as err:  # Drake raises RuntimeError
        raise CalibrationError(f"could not load camera calibration {path}: {err}") from err
    if calib.X_WC.base_frame not in (None, "", "world", "robot_base"):
        raise CalibrationError(
            f"{path}: X_WC.base_frame must be 'world' or 'robot_base', "
            f"got '{calib.X_WC.base_frame}'")
    if not calib.X_WC.IsDeterministic():
        raise CalibrationError(f"{path}: X_WC must be a fixed, finite pose; got a random one")
    err = TransformError(calib.X_WC)
    if err:
        raise CalibrationError(f"{path}: X_WC {err} (a calibration must be a fixed, finite "
                               f"pose)")
    return calib


def CheckCalibrationSerial(calib: CameraCalibration, serial: str, filename: str) -> None:
    """Refuses a calibration made for another camera (``camera_serial`` set
    and different from the connected camera's ``serial``)."""
    if calib.camera_serial and serial and calib.camera_serial != str(serial):
        raise CalibrationError(
            f"the calibration file {filename} is for camera {calib.camera_serial}, the "
            f"connected camera is {serial}")


def CalibrationX_WC(calib: CameraCalibration, X_WB: RigidTransform) -> RigidTransform:
    """The camera pose in world, whichever base frame the file used."""
    X = calib.X_WC.GetDeterministicValue()
    if calib.X_WC.base_frame == "robot_base":
        return X_WB @ X
    return X


# A host name (RFC 1123 labels) or an IPv4 / IPv6 address.
_HOSTNAME = re.compile(r"(?=.{1,253}$)([A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)"
                       r"(\.[A-Za-z0-9]([A-Za-z0-9-]{0,61}[A-Za-z0-9])?)*\.?")


def HostError(host) -> str:
    """'' when ``host`` is an IPv4 / IPv6 address or a host name (checked
    as text: nothing is looked up or connected), else what is wrong."""
    if not isinstance(host, str) or not host.strip():
        return f"must be an IP address or a host name, got {host!r}"
    try:
        ipaddress.ip_address(host.strip("[]"))
        return ""
    except ValueError:
        pass
    if re.fullmatch(r"[0-9.]+", host) or not _HOSTNAME.fullmatch(host):
        return f"must be an IPv4 / IPv6 address or a host name, got {host!r}"
    return ""


def ValidateHardwareConfig(config: HardwareConfig) -> None:
    """Checks values the type system cannot; raises ValueError."""
    ur, grip, cam = config.ur, config.gripper, config.camera

    def need(cond, msg):
        if not cond:
            raise ValueError(f"hardware config: {msg}")
    for key, host in (("ur.robot_ip", ur.robot_ip), ("gripper.host", grip.host or "x")):
        err = HostError(host)
        need(not err, f"{key} {err}")
    need(0.0 < ur.joint_speed_limit <= np.pi,
         f"ur.joint_speed_limit {ur.joint_speed_limit} must be in (0, pi] rad/s")
    need(ur.joint_acceleration_limit > 0, "ur.joint_acceleration_limit must be > 0")
    need(0.03 <= ur.servo_lookahead_time <= 0.2,
         "ur.servo_lookahead_time must be in [0.03, 0.2] s (UR servoj range)")
    need(100 <= ur.servo_gain <= 2000, "ur.servo_gain must be in [100, 2000] (UR servoj range)")
    need(0 < ur.rtde_frequency <= 500, "ur.rtde_frequency must be in (0, 500] Hz")
    need(len(ur.workspace_min) == 3 and len(ur.workspace_max) == 3,
         "ur.workspace_min and ur.workspace_max need 3 values (m)")
    need(all(a < b for a, b in zip(ur.workspace_min, ur.workspace_max)),
         "ur.workspace_min must be below ur.workspace_max on every axis")
    need(ur.command_period > 0, "ur.command_period must be > 0 s")
    need(grip.link in GRIPPER_LINKS, f"gripper.link {grip.link!r} unknown; choose one of "
         f"{', '.join(GRIPPER_LINKS)}")
    need(0 < grip.port < 65536, "gripper.port must be a TCP port")
    if grip.link == "modbus_rtu":
        need(bool(grip.serial_device.strip()),
             "gripper.serial_device must name the RS-485 serial device (link modbus_rtu)")
        need(grip.baud in MODBUS_BAUDS, f"gripper.baud must be one of "
             f"{', '.join(map(str, MODBUS_BAUDS))} bit/s, got {grip.baud}")
        need(1 <= grip.slave_id <= 247, f"gripper.slave_id must be a Modbus slave id in "
             f"1..247, got {grip.slave_id}")
    need(grip.retries >= 0, f"gripper.retries must be >= 0, got {grip.retries}")
    need(grip.activation_timeout > 0, "gripper.activation_timeout must be > 0 s")
    for name in ("speed", "force", "pos_open", "pos_closed"):
        v = getattr(grip, name)
        need(0 <= v <= 255, f"gripper.{name} must be in 0..255 (Robotiq register units)")
    need(grip.pos_open != grip.pos_closed, "gripper.pos_open must differ from pos_closed")
    need(grip.timeout > 0 and grip.update_period > 0,
         "gripper.timeout and gripper.update_period must be > 0 s")
    need(cam.width > 0 and cam.height > 0 and cam.fps > 0,
         "camera width, height and fps must be > 0")
    need(cam.frame_timeout > 0, "camera.frame_timeout must be > 0 s")
    if cam.twin_address:
        host, _, port = cam.twin_address.rpartition(":")
        need(not HostError(host) and port.isdigit() and 0 < int(port) < 65536,
             f"camera.twin_address must be 'host:port', got {cam.twin_address!r}")
