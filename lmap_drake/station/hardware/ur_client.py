"""Thin client for the UR5 over ur_rtde.

``ConnectUr`` imports ``rtde_control`` / ``rtde_receive`` (PyPI ``ur-rtde``)
lazily and builds ``UrClient`` around an ``RTDEControlInterface`` and an
``RTDEReceiveInterface``. ``UrClient`` only uses these methods of them (the
names and argument orders of ur_rtde's Python bindings):

- receive: ``getActualQ()``, ``getActualQd()``, ``getActualTCPForce()``, ``isProtectiveStopped()``,
  ``isEmergencyStopped()``, ``isConnected()``, ``disconnect()``;
- control: ``servoJ(q, speed, acceleration, time, lookahead_time, gain)``,
  ``servoStop(a)``, ``stopScript()``, ``initPeriod()``, ``waitPeriod(t)``,
  ``isConnected()``, ``disconnect()``.

Streaming: after the first accepted target, a daemon thread calls servoJ at
``rtde_frequency``. It moves its servo target linearly from the previous
commanded position to the latest accepted command over one
``command_period`` and, whatever the timing, never faster than
``joint_speed_limit`` per joint. Each cycle it checks for a protective or
emergency stop and for a lost connection; any of these (or an exception from
ur_rtde) records a fault, stops the servo (``servoStop``, ``stopScript``),
and the next ``ReadState`` / ``SetTarget`` raises ``HardwareAbort``.
Commands go through ``SafetyChecker`` first; a refused command never reaches
servoJ and halts the arm.
"""
from __future__ import annotations

import threading
import time

import numpy as np

from lmap_drake.errors import HardwareStationUnavailable
from lmap_drake.station.hardware.safety import HardwareAbort, SafetyChecker, SafetyRefusal
from lmap_drake.station.hardware_config import UrConfig

INSTALL_HINT = "pip install -e .[hardware]"


def _Unavailable(msg: str) -> Exception:
    return HardwareStationUnavailable(msg)


def ImportUrRtde():
    """(rtde_control, rtde_receive) modules, or HardwareStationUnavailable."""
    try:
        import rtde_control  # noqa: F401
        import rtde_receive  # noqa: F401
    except ImportError as err:
        raise _Unavailable(
            f"the hardware station needs ur_rtde (modules rtde_control, rtde_receive), which "
            f"is not installed ({err}); install the hardware extra: {INSTALL_HINT}") from err
    return rtde_control, rtde_receive


def ConnectUr(config: UrConfig, read_only: bool = False) -> "UrClient":
    """Connects to the UR5 at ``config.robot_ip``: the receive interface,
    then (unless ``read_only``) ``UrClient.OpenControl``, which uploads
    ur_rtde's control script. A read-only client cannot command the arm
    (``--dry-run``, and the pre-motion checks before ``OpenControl``)."""
    _, rtde_receive = ImportUrRtde()
    ip = config.robot_ip
    try:
        receive = rtde_receive.RTDEReceiveInterface(ip, config.rtde_frequency)
    except Exception as err:  # ur_rtde raises RuntimeError on connect failures
        raise _Unavailable(
            f"hardware station: could not connect to the UR5 at {ip} (RTDE receive "
            f"interface, port 30004): {err}") from err
    client = UrClient(config, control=None, receive=receive)
    if not read_only:
        try:
            client.OpenControl()
        except BaseException:
            client.Close()
            raise
    return client


class UrClient:
    """UR5 state reading, checked servo streaming, and stopping.

    ``control`` may be None (read-only client). ``clock`` returns seconds
    (monotonic); tests may inject one."""

    def __init__(self, config: UrConfig, control, receive, checker: SafetyChecker | None = None,
                 clock=time.monotonic):
        self.config = config
        self.control = control
        self.receive = receive
        self.checker = checker or SafetyChecker(config)
        self._clock = clock
        self._lock = threading.Lock()
        self._fault: str | None = None
        self._thread: threading.Thread | None = None
        self._stop_event = threading.Event()
        self._last_target: np.ndarray | None = None  # last accepted command
        self._segment = None  # (q_from, q_to, t_start, duration)
        self._q_servo: np.ndarray | None = None  # what servoJ was last sent
        self._halted = False
        self._closed = False
        self.servo_count = 0

    def OpenControl(self) -> None:
        """Opens the RTDE control interface (ur_rtde uploads its control
        script to the controller): from here on the arm can be commanded.
        The first byte that can move the arm: call it after every check."""
        if self.control is not None:
            return
        rtde_control, _ = ImportUrRtde()
        ip = self.config.robot_ip
        try:
            self.control = rtde_control.RTDEControlInterface(ip, self.config.rtde_frequency)
        except Exception as err:
            raise _Unavailable(
                f"hardware station: could not open the RTDE control interface of the UR5 at "
                f"{ip} (is the robot in remote control mode, powered and released?): "
                f"{err}") from err

    # ---- state -------------------------------------------------------------
    @property
    def fault(self) -> str | None:
        return self._fault

    @property
    def streaming(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def last_target(self) -> np.ndarray | None:
        return None if self._last_target is None else self._last_target.copy()

    def _StopStatus(self) -> str | None:
        """A reason to abort read from the robot, or None."""
        if not self.receive.isConnected():
            return f"lost the RTDE connection to the UR5 at {self.config.robot_ip}"
        if self.control is not None and not self.control.isConnected():
            return (f"lost the RTDE control connection to the UR5 at {self.config.robot_ip} "
                    f"(control script stopped)")
        if self.receive.isEmergencyStopped():
            return "the UR5 is emergency stopped"
        if self.receive.isProtectiveStopped():
            return "the UR5 is protective stopped (collision or safety limit)"
        return None

    def CheckHealth(self) -> None:
        """Raises HardwareAbort (after stopping the arm) on a recorded fault,
        a protective or emergency stop, or a lost connection."""
        reason = self._fault
        if reason is None:
            try:
                reason = self._StopStatus()
            except Exception as err:
                reason = f"UR5 status could not be read ({err})"
        if reason is not None:
            self._fault = reason
            self.Halt()
            raise HardwareAbort(f"hardware episode aborted: {reason}; the arm was stopped")

    def ReadState(self) -> tuple[np.ndarray, np.ndarray]:
        """(q rad, v rad/s) of the six joints; raises HardwareAbort."""
        self.CheckHealth()
        try:
            q = np.asarray(self.receive.getActualQ(), dtype=float)
            v = np.asarray(self.receive.getActualQd(), dtype=float)
        except Exception as err:
            self._fault = f"reading the UR5 joint state failed ({err})"
            self.Halt()
            raise HardwareAbort(f"hardware episode aborted: {self._fault}; the arm was "
                                f"stopped") from err
        if q.shape != (6,) or v.shape != (6,):
            raise HardwareAbort(f"UR5 returned {q.size} joint positions and {v.size} "
                                f"velocities, expected 6 and 6")
        return q, v

    def ReadTcpForce(self) -> np.ndarray:
        """The arm's TCP force estimate (N, base frame: the first three of
        ``getActualTCPForce``); zeros when the receive interface has none
        (the force guard then never fires)."""
        read = getattr(self.receive, "getActualTCPForce", None)
        if read is None:
            return np.zeros(3)
        try:
            f = np.asarray(read(), dtype=float).ravel()
        except Exception as err:
            self._fault = f"reading the UR5 TCP force failed ({err})"
            self.Halt()
            raise HardwareAbort(f"hardware episode aborted: {self._fault}; the arm was "
                                f"stopped") from err
        return f[:3] if f.size >= 3 else np.zeros(3)

    # ---- commands ----------------------------------------------------------
    def SetTarget(self, q, dt: float) -> np.ndarray:
        """Checks ``q`` (limits, workspace, and speed against the last
        accepted command, or the measured position for the first one, over
        ``dt`` seconds) and makes it the streaming target. Raises a
        SafetyRefusal (the arm is then stopped) or HardwareAbort."""
        if self.control is None:
            raise HardwareAbort("this UR client is read-only (dry run); it cannot command "
                                "the arm")
        self.CheckHealth()
        if self._halted:
            raise HardwareAbort("the UR5 client was stopped; build a new station to move again")
        q_prev = self._last_target
        if q_prev is None:
            q_prev, _ = self.ReadState()
        try:
            q = self.checker.Check(q, q_prev, dt)
        except SafetyRefusal:
            self._fault = "a command was refused by the safety checks"
            self.Halt()
            raise
        now = self._clock()
        with self._lock:
            q_from = self._q_servo if self._q_servo is not None else q_prev.copy()
            self._segment = (q_from.copy(), q.copy(), now, float(dt))
            if self._q_servo is None:
                self._q_servo = q_from.copy()
            self._last_target = q.copy()
        if self._thread is None:
            self._thread = threading.Thread(target=self._StreamLoop, name="ur5_servoj",
                                            daemon=True)
            self._thread.start()
        return q

    def _NextServoTarget(self, period: float) -> np.ndarray:
        with self._lock:
            q_from, q_to, t0, duration = self._segment
            alpha = 1.0 if duration <= 0 else min(1.0, max(0.0, (self._clock() - t0) / duration))
            desired = q_from + alpha * (q_to - q_from)
            max_step = self.checker.speed_limit * period
            step = np.clip(desired - self._q_servo, -max_step, max_step)
            self._q_servo = self._q_servo + step
            return self._q_servo.copy()

    def _StreamLoop(self) -> None:
        cfg = self.config
        period = 1.0 / cfg.rtde_frequency
        try:
            while not self._stop_event.is_set():
                t_start = self.control.initPeriod()
                reason = self._StopStatus()
                if reason is not None:
                    self._fault = reason
                    break
                q = self._NextServoTarget(period)
                ok = self.control.servoJ(q.tolist(), cfg.joint_speed_limit,
                                         cfg.joint_acceleration_limit, period,
                                         cfg.servo_lookahead_time, cfg.servo_gain)
                self.servo_count += 1
                if ok is False:
                    # Usually a stop the status stream has not shown yet:
                    # name it when it shows within 0.1 s.
                    self._fault = self._StopReasonSoon() or \
                        "servoJ was rejected by the UR5 controller"
                    break
                self.control.waitPeriod(t_start)
        except Exception as err:  # ur_rtde raises RuntimeError when the link drops
            self._fault = f"UR5 streaming failed ({err})"
        if self._fault is not None:
            self._StopArm()

    def _StopReasonSoon(self, wait: float = 0.1, poll: float = 0.01) -> str | None:
        """The stop reason the robot reports within ``wait`` s, or None."""
        t_end = time.monotonic() + wait
        while True:
            try:
                reason = self._StopStatus()
            except Exception:  # noqa: BLE001 - the link itself failed
                return None
            if reason is not None or time.monotonic() >= t_end:
                return reason
            time.sleep(poll)

    # ---- stopping ----------------------------------------------------------
    def _StopArm(self) -> None:
        if self.control is None:
            return
        for call in (lambda: self.control.servoStop(self.config.joint_acceleration_limit * 2),
                     self.control.stopScript):
            try:
                call()
            except Exception:
                pass

    def Halt(self) -> None:
        """Stops streaming and the servo (idempotent); the connection stays."""
        self._stop_event.set()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=1.0)
        if not self._halted:
            self._halted = True
            self._StopArm()

    def Close(self) -> None:
        """Halts, then disconnects both interfaces (idempotent)."""
        if self._closed:
            return
        self.Halt()
        self._closed = True
        for iface in (self.control, self.receive):
            if iface is None:
                continue
            try:
                iface.disconnect()
            except Exception:
                pass
