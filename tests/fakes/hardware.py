"""FAKE devices for the tests (under tests/: not part of the product). Nothing here talks to a
real robot, gripper or camera.

- ``FakeRTDEControlInterface`` / ``FakeRTDEReceiveInterface``: the subset of
  ur_rtde's ``rtde_control.RTDEControlInterface`` and
  ``rtde_receive.RTDEReceiveInterface`` methods that ``UrClient`` uses, with
  the same names and argument orders. The fake arm tracks servoJ targets
  perfectly; flags simulate protective / emergency stops and a dropped link.
- ``FakeRobotiqServer``: a TCP server on localhost that speaks the Robotiq
  URCap ASCII protocol (``SET ... -> ack``, ``GET VAR -> VAR value``; the
  twin's ``RobotiqSocketServer``) with a simple fake gripper behind it
  (``FakeGripper``: activation delay, finite finger speed).
- (``fakes.modbus.FakeModbusGripperServer``: the same fake gripper as a
  Modbus RTU slave on a pseudo-terminal.)
- ``FakePyrealsense2``: a stand-in for the ``pyrealsense2`` module exposing
  the names ``ConnectRealSense`` uses (``pipeline``, ``config``, ``align``,
  ``stream``, ``format``, ``camera_info``); frames show a synthetic scene.
"""
from __future__ import annotations

import dataclasses as dc
import threading
import time
import types

import numpy as np

from lmap_drake.station.hardware.realsense_client import ConnectRealSense
from lmap_drake.station.hardware.robotiq_client import RobotiqClient
from lmap_drake.station.hardware.robotiq_modbus_client import RobotiqModbusClient
from lmap_drake.station.hardware.ur_client import UrClient
from lmap_drake.twin.robotiq_server import RobotiqSocketServer


# ---------------------------------------------------------------- UR (fake)
class FakeRTDEReceiveInterface:
    """FAKE ur_rtde RTDEReceiveInterface: joint state of a fake arm."""

    def __init__(self, hostname: str = "fake", frequency: float = -1.0, q=None):
        self.hostname = hostname
        self.q = np.array(q if q is not None else [0.0, -1.5, 1.5, -1.57, -1.57, 0.0], float)
        self.qd = np.zeros(6)
        self.tcp_force = np.zeros(6)      # N, N m: what the fake arm's TCP estimate reads
        self.protective_stopped = False
        self.emergency_stopped = False
        self.connected = True
        self.fail_reads = False

    def getActualQ(self):
        if self.fail_reads:
            raise RuntimeError("fake: RTDE receive timed out")
        return self.q.tolist()

    def getActualQd(self):
        return self.qd.tolist()

    def getActualTCPForce(self):
        return self.tcp_force.tolist()

    def isProtectiveStopped(self):
        return self.protective_stopped

    def isEmergencyStopped(self):
        return self.emergency_stopped

    def isConnected(self):
        return self.connected

    def disconnect(self):
        self.connected = False


class FakeRTDEControlInterface:
    """FAKE ur_rtde RTDEControlInterface: records every call; the fake arm
    (a FakeRTDEReceiveInterface) jumps to each servoJ target."""

    def __init__(self, receive: FakeRTDEReceiveInterface, hostname: str = "fake",
                 frequency: float = -1.0):
        self.receive = receive
        self.hostname = hostname
        self.frequency = frequency
        self.servoj_calls: list[tuple] = []
        self.servo_stops: list[float] = []
        self.script_stops = 0
        self.connected = True
        self._lock = threading.Lock()

    def servoJ(self, q, speed, acceleration, time_, lookahead_time, gain):
        with self._lock:
            self.servoj_calls.append((list(q), speed, acceleration, time_, lookahead_time, gain))
        dt = max(time_, 1e-6)
        self.receive.qd = (np.asarray(q, float) - self.receive.q) / dt
        self.receive.q = np.asarray(q, float)
        return True

    def servoStop(self, a=10.0):
        self.servo_stops.append(a)
        self.receive.qd = np.zeros(6)
        return True

    def stopScript(self):
        self.script_stops += 1

    def initPeriod(self):
        return time.monotonic()

    def waitPeriod(self, t_cycle_start):
        period = 1.0 / self.frequency if self.frequency > 0 else 0.002
        remaining = t_cycle_start + period - time.monotonic()
        if remaining > 0:
            time.sleep(remaining)

    def isConnected(self):
        return self.connected

    def disconnect(self):
        self.connected = False

    @property
    def servoed_qs(self) -> list[list[float]]:
        with self._lock:
            return [c[0] for c in self.servoj_calls]


def MakeFakeUrClient(config, q0=None, read_only: bool = False) -> UrClient:
    """A UrClient over fake ur_rtde interfaces (no robot)."""
    receive = FakeRTDEReceiveInterface(config.robot_ip, config.rtde_frequency, q0)
    control = None if read_only else FakeRTDEControlInterface(
        receive, config.robot_ip, config.rtde_frequency)
    return UrClient(config, control=control, receive=receive)


# ----------------------------------------------------------- Robotiq (fake)
class FakeGripper:
    """FAKE 2F-85 register model behind FakeRobotiqServer."""

    def __init__(self, activation_time: float = 0.05, speed_units_per_s: float = 2000.0,
                 object_pos: int | None = None):
        """``object_pos``: the fingers stall there when closing past it (a
        held object, e.g. a leaf), reporting OBJ 2 (object detected while
        closing), as the real 2F-85 does."""
        self.regs = {k: 0 for k in ("ACT", "GTO", "ATR", "ADR", "POS", "PRE", "SPE", "FOR",
                                    "OBJ", "STA", "FLT", "MOD")}
        self.activation_time = activation_time
        self.speed = speed_units_per_s
        self.object_pos = object_pos
        self._t_act = None
        self._move = None  # (pos_from, pos_to, t0)
        self.lock = threading.Lock()

    def _Refresh(self, now: float) -> None:
        r = self.regs
        if self._t_act is not None and r["STA"] != 3 and now - self._t_act >= self.activation_time:
            r["STA"] = 3
        if self._move is not None:
            p0, p1, t0 = self._move
            travel = self.speed * (now - t0)
            stop = self.object_pos
            if stop is not None and p0 <= stop < p1 and p0 + travel >= stop:
                r["POS"], r["OBJ"], self._move = stop, 2, None    # stalled on the object
            elif travel >= abs(p1 - p0):
                r["POS"], r["OBJ"], self._move = p1, 3, None
            else:
                r["POS"] = int(round(p0 + np.sign(p1 - p0) * travel))
                r["OBJ"] = 0

    def Set(self, values: dict[str, int]) -> bool:
        now = time.monotonic()
        with self.lock:
            self._Refresh(now)
            for k in values:
                if k not in self.regs:
                    return False
            values = dict(values)
            requested = values.pop("POS", None)  # SET POS is the request; GET POS the fingers
            self.regs.update(values)
            if values.get("ACT") == 0:
                self.regs["STA"], self._t_act = 0, None
            elif values.get("ACT") == 1 and self._t_act is None:
                self.regs["STA"], self._t_act = 1, now
            if requested is not None:
                self.regs["PRE"] = requested
            if self.regs["GTO"] == 1 and self.regs["STA"] == 3 and (
                    requested is not None or "GTO" in values):
                self._move = (self.regs["POS"], self.regs["PRE"], now)
                self.regs["OBJ"] = 0
        return True

    def Get(self, var: str) -> int | None:
        with self.lock:
            self._Refresh(time.monotonic())
            return self.regs.get(var)


class FakeRobotiqServer(RobotiqSocketServer):
    """FAKE Robotiq URCap socket server: ``twin.robotiq_server.
    RobotiqSocketServer`` over a ``FakeGripper`` unless ``gripper`` is given
    (``received`` lists every request line; ``silent`` stops replies;
    ``DropClients`` closes every connection, a lost link)."""

    def __init__(self, gripper: FakeGripper | None = None, host: str = "127.0.0.1",
                 port: int = 0):
        super().__init__(gripper or FakeGripper(), host, port)



# ----------------------------------------------------- RealSense (fake)
class _FakeFrame:
    def __init__(self, data: np.ndarray):
        self._data = data

    def get_data(self):
        return self._data

    def __bool__(self):
        return True


class _FakeFrameset:
    def __init__(self, color: np.ndarray, depth: np.ndarray, aligned: bool):
        self.color, self.depth, self.aligned = color, depth, aligned

    def get_color_frame(self):
        return _FakeFrame(self.color)

    def get_depth_frame(self):
        return _FakeFrame(self.depth)


class FakePyrealsense2:
    """FAKE ``pyrealsense2`` module: one fake camera whose colour image is a
    red disc on grey and whose raw depth (z16) is a plane at ``plane_depth``
    metres with the disc nearer, and a band of zeros (no return) on the left.
    Unaligned framesets carry depth at the depth stream's size; ``align``
    resamples it to colour, as the real ``rs.align`` does."""

    class stream:  # noqa: N801 (pyrealsense2 names)
        depth = "stream.depth"
        color = "stream.color"

    class format:  # noqa: N801
        z16 = "format.z16"
        rgb8 = "format.rgb8"

    class camera_info:  # noqa: N801
        serial_number = "camera_info.serial_number"

    def __init__(self, serial: str = "f0000001", depth_scale: float = 0.00025,
                 plane_depth: float = 0.8, disc_depth: float = 0.6, frames=None,
                 intrinsics=None):
        """``frames`` (rgb HxWx3 or HxWx4 uint8, depth HxW metres, inf = no
        return; e.g. a render of the plant world) replaces the synthetic
        scene; ``intrinsics`` (fx, fy, cx, cy in pixels) the fake lens."""
        self.serial = serial
        self.depth_scale = depth_scale
        self.plane_depth = plane_depth
        self.disc_depth = disc_depth
        self.frames = frames
        self.intrinsics = intrinsics
        self.started = self.stopped = 0
        self.last_config = None
        self.frames_served = 0

    def config(self):
        outer = self

        class _Config:
            def __init__(self):
                self.device = None
                self.streams = {}
                outer.last_config = self

            def enable_device(self, serial):
                self.device = serial

            def enable_stream(self, stream, width, height, fmt, fps):
                self.streams[stream] = (width, height, fmt, fps)
        return _Config()

    def pipeline(self):
        return _FakePipeline(self)

    def align(self, to_stream):
        outer = self

        class _Align:
            def process(self, frames: _FakeFrameset):
                if to_stream != outer.stream.color:
                    raise RuntimeError("fake: only align-to-colour is modelled")
                h, w = frames.color.shape[:2]
                d = frames.depth
                rows = (np.arange(h) * d.shape[0] // h)
                cols = (np.arange(w) * d.shape[1] // w)
                return _FakeFrameset(frames.color, d[np.ix_(rows, cols)], True)
        return _Align()

    def Render(self, width: int, height: int, dwidth: int, dheight: int):
        """(colour HxWx3 uint8, raw depth dh x dw uint16)."""
        if self.frames is not None:
            rgb, metres = self.frames
            rgb = np.asarray(rgb)[..., :3]
            if rgb.shape[:2] != (height, width) or np.shape(metres) != (dheight, dwidth):
                raise RuntimeError(f"fake: frames are {rgb.shape[:2]} / {np.shape(metres)}, "
                                   f"streams {height}x{width} / {dheight}x{dwidth}")
            m = np.asarray(metres, float)
            raw = np.where(np.isfinite(m) & (m > 0), np.round(m / self.depth_scale), 0)
            return np.ascontiguousarray(rgb, np.uint8), np.clip(raw, 0, 65535).astype(np.uint16)
        yy, xx = np.mgrid[0:height, 0:width]
        disc = (xx - width / 2) ** 2 + (yy - height / 2) ** 2 < (height / 6) ** 2
        color = np.full((height, width, 3), 128, np.uint8)
        color[disc] = (200, 20, 20)
        dy, dx = np.mgrid[0:dheight, 0:dwidth]
        ddisc = (dx - dwidth / 2) ** 2 + (dy - dheight / 2) ** 2 < (dheight / 6) ** 2
        depth = np.full((dheight, dwidth), round(self.plane_depth / self.depth_scale), np.uint16)
        depth[ddisc] = round(self.disc_depth / self.depth_scale)
        depth[:, : dwidth // 10] = 0
        return color, depth


class _FakePipeline:
    def __init__(self, rs: FakePyrealsense2):
        self.rs = rs
        self.cfg = None

    def start(self, cfg):
        if cfg.device not in (None, self.rs.serial):
            raise RuntimeError(f"fake: no device with serial {cfg.device}")
        for s in (self.rs.stream.color, self.rs.stream.depth):
            if s not in cfg.streams:
                raise RuntimeError(f"fake: stream {s} not enabled")
        self.cfg = cfg
        self.rs.started += 1
        return _FakeProfile(self.rs, cfg)

    def wait_for_frames(self, timeout_ms=5000):
        w, h, _, _ = self.cfg.streams[self.rs.stream.color]
        dw, dh, _, _ = self.cfg.streams[self.rs.stream.depth]
        color, depth = self.rs.Render(w, h, dw, dh)
        self.rs.frames_served += 1
        return _FakeFrameset(color, depth, False)

    def stop(self):
        self.rs.stopped += 1


class _FakeProfile:
    def __init__(self, rs: FakePyrealsense2, cfg):
        self.rs, self.cfg = rs, cfg

    def get_device(self):
        rs = self.rs
        return types.SimpleNamespace(
            get_info=lambda key: rs.serial if key == rs.camera_info.serial_number else "",
            first_depth_sensor=lambda: types.SimpleNamespace(
                get_depth_scale=lambda: rs.depth_scale))

    def get_stream(self, stream):
        w, h, _, _ = self.cfg.streams[stream]
        if self.rs.intrinsics is not None:
            fx, fy, cx, cy = self.rs.intrinsics
        else:
            fx, fy, cx, cy = 0.713 * w, 0.714 * w, w / 2 + 3.5, h / 2 - 2.5
        intr = types.SimpleNamespace(width=w, height=h, fx=fx, fy=fy, ppx=cx, ppy=cy)
        vsp = types.SimpleNamespace(get_intrinsics=lambda: intr)
        return types.SimpleNamespace(as_video_stream_profile=lambda: vsp)


def MakeFakeHardwareClients(config, q0=None, gripper_server=None,
                            rs: FakePyrealsense2 | None = None, read_only: bool = False):
    """HardwareClients over fakes: fake ur_rtde interfaces, the gripper
    client connected to ``gripper_server`` (required: a running
    FakeRobotiqServer, then a RobotiqClient on its port; or a running
    ``fakes.modbus.FakeModbusGripperServer``, then a RobotiqModbusClient on
    its pty, with ``config.gripper``'s Modbus settings), and a
    RealSenseClient over ``FakePyrealsense2``."""
    from lmap_drake.station.hardware.station import HardwareClients

    if gripper_server is None:
        raise ValueError("start a FakeRobotiqServer and pass it as gripper_server")
    ur = MakeFakeUrClient(config.ur, q0, read_only=read_only)
    if hasattr(gripper_server, "device"):          # a FakeModbusGripperServer
        gcfg = dc.replace(config.gripper, link="modbus_rtu", serial_device=gripper_server.device)
        gripper = RobotiqModbusClient.Connect(gcfg)
    else:
        gcfg = dc.replace(config.gripper, port=gripper_server.port)
        gripper = RobotiqClient.Connect(gcfg, "127.0.0.1")
    if gcfg.activate and not read_only:
        gripper.Activate(timeout=2.0)
    camera_rs = rs or FakePyrealsense2()
    camera = ConnectRealSense(config.camera, rs=camera_rs)
    return HardwareClients(ur, gripper, camera)
