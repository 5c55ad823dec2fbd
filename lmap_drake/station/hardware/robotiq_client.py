"""Thin client for the Robotiq 2F-85 through the Robotiq URCap's socket.

The URCap on the UR controller listens on TCP port 63352 and speaks ASCII,
one request per line:

- ``SET <VAR> <int> [<VAR> <int> ...]\\n`` -> ``ack``
- ``GET <VAR>\\n`` -> ``<VAR> <int>``

Variables used here: ``ACT`` (1 = activated), ``GTO`` (1 = go to the
requested position), ``ATR`` (auto-release, 0), ``POS`` (position 0..255:
0 open, 255 closed), ``SPE`` / ``FOR`` (speed / force 0..255), ``STA``
(0 reset, 1 activating, 3 active), ``OBJ`` (0 moving, 1 stopped on an object
while opening, 2 stopped on an object while closing, 3 at the requested
position), ``FLT`` (fault code, 0 none).

Opening (m) <-> POS is linear between ``pos_open`` (85 mm) and
``pos_closed`` (0 mm): an approximation, since the 2F-85's linkage is not
exactly linear and each gripper's calibrated range differs a little.
"""
from __future__ import annotations

import socket
import threading
import time

import numpy as np

from lmap_drake.errors import HardwareStationUnavailable
from lmap_drake.station.hardware.safety import HardwareAbort, SafetyRefusal
from lmap_drake.station.hardware_config import GripperConfig
from lmap_drake.robot import GRIPPER_MAX_WIDTH

STA_RESET, STA_ACTIVATING, STA_ACTIVE = 0, 1, 3
OBJ_MOVING, OBJ_STOPPED_OPENING, OBJ_STOPPED_CLOSING, OBJ_AT_REQUEST = 0, 1, 2, 3


class RobotiqError(HardwareAbort):
    """The gripper did not answer, answered something unexpected, or the
    socket closed."""


class GripperCommandRefusal(SafetyRefusal):
    """A gripper opening command is not finite or outside [0, 0.085] m."""


def OpeningToPos(opening: float, config: GripperConfig) -> int:
    """POS register value (0..255) for an opening in metres."""
    frac = float(np.clip(opening / GRIPPER_MAX_WIDTH, 0.0, 1.0))  # 1 = open
    return int(round(config.pos_closed + frac * (config.pos_open - config.pos_closed)))


def PosToOpening(pos: int, config: GripperConfig) -> float:
    """Opening in metres for a POS register value (clipped to [0, 0.085])."""
    frac = (pos - config.pos_closed) / float(config.pos_open - config.pos_closed)
    return float(np.clip(frac, 0.0, 1.0) * GRIPPER_MAX_WIDTH)


def CheckOpeningCommand(opening) -> float:
    """The commanded opening as a float, or GripperCommandRefusal."""
    o = np.asarray(opening, dtype=float).reshape(-1)
    if o.shape != (1,) or not np.isfinite(o[0]) or not -1e-9 <= o[0] <= GRIPPER_MAX_WIDTH + 1e-9:
        raise GripperCommandRefusal(
            f"refused gripper command {o.tolist()}: the opening must be one finite value in "
            f"[0, {GRIPPER_MAX_WIDTH}] m")
    return float(np.clip(o[0], 0.0, GRIPPER_MAX_WIDTH))


class GripperRegisters:
    """The 2F-85 operations both links share, on top of a link's ``Get``,
    ``MoveToPos`` and ``config`` (URCap socket: ``RobotiqClient``; Modbus
    RTU: ``RobotiqModbusClient``)."""

    def MoveToOpening(self, opening: float) -> int:
        """Checks the opening (m) and moves there; returns the POS sent."""
        pos = OpeningToPos(CheckOpeningCommand(opening), self.config)
        self.MoveToPos(pos)
        return pos

    def Position(self) -> int:
        return self.Get("POS")

    def Opening(self) -> float:
        """Measured opening in metres."""
        return PosToOpening(self.Position(), self.config)

    def ObjectStatus(self) -> int:
        return self.Get("OBJ")


class RobotiqClient(GripperRegisters):
    """Request/reply client over one TCP socket (thread-safe)."""

    def __init__(self, config: GripperConfig, sock: socket.socket, host: str = ""):
        self.config = config
        self.host = host
        self._sock = sock
        self._sock.settimeout(config.timeout)
        self._lock = threading.Lock()
        self.last_pos_sent: int | None = None

    @classmethod
    def Connect(cls, config: GripperConfig, host: str) -> "RobotiqClient":
        """Opens the socket to ``host:config.port``; raises
        HardwareStationUnavailable when nothing answers."""
        try:
            sock = socket.create_connection((host, config.port), timeout=config.timeout)
        except OSError as err:
            raise HardwareStationUnavailable(
                f"hardware station: could not connect to the Robotiq gripper socket at "
                f"{host}:{config.port} (is the Robotiq URCap installed and the gripper "
                f"enabled?): {err}") from err
        return cls(config, sock, host)

    # ---- protocol ----------------------------------------------------------
    def _Request(self, line: str) -> str:
        with self._lock:
            try:
                self._sock.sendall((line + "\n").encode("ascii"))
                data = self._sock.recv(1024)
            except socket.timeout as err:
                raise RobotiqError(f"gripper at {self.host}:{self.config.port} did not answer "
                                   f"'{line}' within {self.config.timeout} s") from err
            except OSError as err:
                raise RobotiqError(f"lost the connection to the gripper at {self.host}:"
                                   f"{self.config.port} ({err})") from err
        if not data:
            raise RobotiqError(f"the gripper at {self.host}:{self.config.port} closed the "
                               f"connection")
        return data.decode("ascii", errors="replace").strip()

    def Set(self, **values: int) -> None:
        """``SET K1 V1 K2 V2 ...``; raises RobotiqError without ``ack``."""
        parts = []
        for key, value in values.items():
            parts += [key.upper(), str(int(value))]
        line = "SET " + " ".join(parts)
        reply = self._Request(line)
        if reply != "ack":
            raise RobotiqError(f"gripper refused '{line}': replied '{reply}'")

    def Get(self, var: str) -> int:
        """``GET VAR`` -> integer value; raises RobotiqError."""
        var = var.upper()
        reply = self._Request(f"GET {var}")
        parts = reply.split()
        if len(parts) != 2 or parts[0] != var:
            raise RobotiqError(f"unexpected gripper reply to 'GET {var}': '{reply}'")
        try:
            return int(parts[1])
        except ValueError as err:
            raise RobotiqError(f"unexpected gripper reply to 'GET {var}': '{reply}'") from err

    # ---- operations --------------------------------------------------------
    def IsActive(self) -> bool:
        return self.Get("STA") == STA_ACTIVE

    def Activate(self, timeout: float | None = None, poll: float = 0.05) -> None:
        """Activates the gripper unless it is already active (activation of
        an inactive 2F-85 opens and closes it once to calibrate). Raises
        RobotiqError if it is not active within ``timeout``."""
        if self.IsActive():
            return
        self.Set(ACT=0, ATR=0)
        self.Set(ACT=1)
        deadline = time.monotonic() + (timeout if timeout is not None else 10.0)
        while time.monotonic() < deadline:
            if self.IsActive():
                return
            time.sleep(poll)
        raise RobotiqError(f"gripper did not become active (STA 3) within "
                           f"{timeout if timeout is not None else 10.0} s")

    def MoveToPos(self, pos: int) -> None:
        """Requests POS with the configured speed and force, and GTO 1."""
        pos = int(np.clip(pos, 0, 255))
        self.Set(POS=pos, SPE=self.config.speed, FOR=self.config.force, GTO=1)
        self.last_pos_sent = pos

    def Measure(self) -> tuple[float, int]:
        """(opening m, OBJ) for one driver sample: ``GET OBJ`` first, then
        ``GET POS``, so the opening is never older than the object flag (the
        fingers may stop on an object between two requests; an opening read
        before it, paired with OBJ 2, overstates where they hold)."""
        obj = self.ObjectStatus()
        return self.Opening(), obj

    def Status(self) -> int:
        return self.Get("STA")

    def Close(self) -> None:
        try:
            self._sock.close()
        except OSError:
            pass
