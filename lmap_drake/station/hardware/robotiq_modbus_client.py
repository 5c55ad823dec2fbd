"""Thin client for the Robotiq 2F-85 over Modbus RTU (RS-485), with pymodbus.

The gripper is a Modbus RTU slave (factory settings: slave 9, 115200 baud,
8 data bits, no parity, 1 stop bit). The robot writes its three output
registers from 0x03E8 (function 16, preset multiple registers) and reads its
three input registers from 0x07D0 (function 3, read holding registers), each
register two bytes, high byte first (the 2F-85 instruction manual, section
"Control"):

=========  ================================================  =====================
register   high byte                                         low byte
=========  ================================================  =====================
0x03E8     action request: rACT bit 0, rGTO bit 3,           reserved
           rATR bit 4, rARD bit 5
0x03E9     reserved                                          position request rPR
0x03EA     speed rSP                                         force rFR
0x07D0     gripper status: gACT bit 0, gGTO bit 3,           reserved
           gSTA bits 4-5, gOBJ bits 6-7
0x07D1     fault status: gFLT bits 0-3 (kFLT bits 4-7)       position request echo gPR
0x07D2     position gPO                                      current gCU (x 10 mA)
=========  ================================================  =====================

``RobotiqModbusClient`` has the methods of the socket client
(``robotiq_client.RobotiqClient``), with the same variable names (``ACT``,
``GTO``, ``ATR``, ``ADR``, ``POS``, ``SPE``, ``FOR`` requested; ``STA``,
``OBJ``, ``FLT``, ``PRE`` echo, ``POS`` position, ``CUR`` read), so the
hardware station drives either. The three output registers are always
written together, so the client keeps the last request and changes only the
fields a call names. A reply missing within ``timeout`` (after ``retries``
resends) or a serial error is a lost link (``RobotiqError``, a
``HardwareAbort``: the station stops the arm and sends the gripper nothing
more, so a held leaf stays held). A gripper fault (gFLT) other than 0x09 is
``RobotiqFault`` on the next read, and a move is sent only after a status
read without one; 0x09 ("no communication for at least
1 s") is what a pause in polling, such as planning, leaves, and is not an
abort. A reset and activation clears a fault (``Activate``).

pymodbus (``pip install -e .[hardware]``) is imported when a client
connects, like ur_rtde.
"""
from __future__ import annotations

import logging
import os
import threading
import time

from lmap_drake.errors import HardwareStationUnavailable
from lmap_drake.station.hardware.robotiq_client import (STA_ACTIVE, GripperRegisters,
                                                        PosToOpening, RobotiqError)
from lmap_drake.station.hardware_config import GripperConfig

INSTALL_HINT = "pip install -e .[hardware]"
REQUEST_ADDRESS, STATUS_ADDRESS = 0x03E8, 0x07D0
REQUEST_FIELDS = ("ACT", "GTO", "ATR", "ADR", "POS", "SPE", "FOR")
STATUS_FIELDS = ("ACT", "GTO", "STA", "OBJ", "FLT", "KFLT", "PRE", "POS", "CUR")
FAULTS = {
    0x05: "action delayed: the activation (or reactivation) must complete first",
    0x07: "the activation bit must be set before any action",
    0x08: "maximum operating temperature exceeded: let it cool down",
    0x09: "no communication for at least 1 s",
    0x0A: "under the minimum operating voltage",
    0x0B: "automatic release in progress",
    0x0C: "internal fault: contact Robotiq support",
    0x0D: "activation fault: check that nothing blocks the fingers",
    0x0E: "overcurrent triggered",
    0x0F: "automatic release completed",
}
NOT_AN_ABORT = (0x00, 0x09)


class RobotiqFault(RobotiqError):
    """The gripper reports a fault (gFLT); it does not move until reset and
    reactivated."""


def ImportPymodbus():
    """(ModbusSerialClient, ModbusException), or HardwareStationUnavailable."""
    try:
        from pymodbus.client import ModbusSerialClient
        from pymodbus.exceptions import ModbusException
    except ImportError as err:
        raise HardwareStationUnavailable(
            f"hardware.gripper.link modbus_rtu needs pymodbus (with pyserial), which is not "
            f"installed ({err}); install the hardware extra: {INSTALL_HINT}") from err
    # pymodbus logs a lost reply itself; RobotiqError says it once, in the run's words.
    # (a handler on its logger keeps Python's last-resort stderr handler away)
    logging.getLogger("pymodbus").addHandler(logging.NullHandler())
    return ModbusSerialClient, ModbusException


def RequestRegisters(request: dict) -> list[int]:
    """The three output registers (0x03E8..0x03EA) for a request dict with
    ``REQUEST_FIELDS`` (bits 0/1, bytes 0..255)."""
    action = ((request["ACT"] & 1) | (request["GTO"] & 1) << 3 | (request["ATR"] & 1) << 4
              | (request["ADR"] & 1) << 5)
    return [action << 8, request["POS"] & 0xFF,
            (request["SPE"] & 0xFF) << 8 | (request["FOR"] & 0xFF)]


def StatusFromRegisters(registers) -> dict:
    """The status dict (``STATUS_FIELDS``) of the three input registers
    (0x07D0..0x07D2)."""
    status, fault = registers[0] >> 8 & 0xFF, registers[1] >> 8 & 0xFF
    return {"ACT": status & 1, "GTO": status >> 3 & 1, "STA": status >> 4 & 3,
            "OBJ": status >> 6 & 3, "FLT": fault & 0x0F, "KFLT": fault >> 4,
            "PRE": registers[1] & 0xFF, "POS": registers[2] >> 8 & 0xFF,
            "CUR": registers[2] & 0xFF}


def FaultText(code: int) -> str:
    return f"0x{code:02X} ({FAULTS.get(code, 'unknown fault code')})"


class RobotiqModbusClient(GripperRegisters):
    """Request/reply client over one pymodbus ``ModbusSerialClient``
    (thread-safe). ``Connect`` opens it; tests may pass any client with the
    same methods."""

    def __init__(self, config: GripperConfig, modbus):
        self.config = config
        self._modbus = modbus
        self._lock = threading.Lock()
        self._request = {k: 0 for k in REQUEST_FIELDS}
        self._request.update(SPE=config.speed, FOR=config.force)
        self.last_pos_sent: int | None = None
        self.last_status: dict | None = None

    @property
    def where(self) -> str:
        c = self.config
        return f"{c.serial_device} (Modbus slave {c.slave_id}, {c.baud} baud)"

    @classmethod
    def Connect(cls, config: GripperConfig) -> "RobotiqModbusClient":
        """Opens ``config.serial_device`` and reads the gripper's status once;
        raises HardwareStationUnavailable when the device cannot be opened or
        no gripper answers. Sends nothing that moves the gripper."""
        ModbusSerialClient, _ = ImportPymodbus()
        device = config.serial_device
        if not os.path.exists(device):
            raise HardwareStationUnavailable(
                f"hardware station: the gripper's serial device {device} does not exist "
                f"(hardware.gripper.serial_device; is the RS-485 adapter plugged in? see "
                f"ls /dev/serial/by-id/)")
        if not os.access(device, os.R_OK | os.W_OK):
            raise HardwareStationUnavailable(
                f"hardware station: no permission to open the gripper's serial device {device}: "
                f"add your user to its group (sudo usermod -aG dialout $USER, then log in "
                f"again) or install a udev rule (docs/how-to/hardware-bring-up.md)")
        modbus = ModbusSerialClient(device, baudrate=config.baud, bytesize=8, parity="N",
                                    stopbits=1, timeout=config.timeout, retries=config.retries)
        if not modbus.connect():
            raise HardwareStationUnavailable(
                f"hardware station: could not open the gripper's serial device {device} "
                f"(in use by another program?)")
        client = cls(config, modbus)
        try:
            status = client.ReadStatus(check_fault=False)
        except RobotiqError as err:
            client.Close()
            raise HardwareStationUnavailable(
                f"hardware station: no Robotiq gripper answered on {client.where}: check the "
                f"RS-485 wiring (A/B), the gripper's 24 V supply and hardware.gripper.slave_id "
                f"and baud ({err})") from err
        # continue from what the gripper is doing: a write never drops rACT by accident
        client._request.update(ACT=status["ACT"], GTO=status["GTO"], POS=status["PRE"])
        return client

    # ---- protocol ----------------------------------------------------------
    def _Call(self, what: str, method: str, *args, **kwargs):
        _, ModbusException = ImportPymodbus()
        if self._modbus is None:
            raise RobotiqError(f"the link to the gripper on {self.where} is closed")
        try:
            reply = getattr(self._modbus, method)(*args, device_id=self.config.slave_id,
                                                  **kwargs)
        except (ModbusException, OSError) as err:
            tries = self.config.retries + 1
            raise RobotiqError(
                f"lost the link to the gripper on {self.where}: no reply to {what} within "
                f"{self.config.timeout} s ({tries} {'try' if tries == 1 else 'tries'}): "
                f"{' '.join(str(err).split())}") from err
        if reply is None or reply.isError():
            raise RobotiqError(f"the gripper on {self.where} refused {what}: {reply}")
        return reply

    def ReadStatus(self, check_fault: bool = True) -> dict:
        """Reads 0x07D0..0x07D2 (``STATUS_FIELDS``); raises RobotiqFault on a
        fault other than 0x09 unless ``check_fault`` is False."""
        reply = self._Call("the status read (0x07D0)", "read_holding_registers",
                           STATUS_ADDRESS, count=3)
        if len(reply.registers) != 3:
            raise RobotiqError(f"the gripper on {self.where} answered the status read with "
                               f"{len(reply.registers)} registers, not 3")
        status = StatusFromRegisters(reply.registers)
        self.last_status = status
        if check_fault and status["FLT"] not in NOT_AN_ABORT:
            raise RobotiqFault(
                f"the gripper on {self.where} reports fault {FaultText(status['FLT'])}; it "
                f"stays as it is: clear the fault, then reset and reactivate it")
        return status

    def Set(self, **values: int) -> None:
        """Changes the named request fields (``REQUEST_FIELDS``) and writes
        the three output registers."""
        with self._lock:
            request = dict(self._request)
            for key, value in values.items():
                key = key.upper()
                if key not in REQUEST_FIELDS:
                    raise RobotiqError(f"unknown gripper request field {key!r}; the 2F-85 "
                                       f"takes {', '.join(REQUEST_FIELDS)}")
                request[key] = int(value)
            registers = RequestRegisters(request)
            self._Call("the request write (0x03E8)", "write_registers", REQUEST_ADDRESS,
                       registers)
            self._request = request

    def Get(self, var: str) -> int:
        """One status field (``STATUS_FIELDS``) from a fresh status read."""
        var = var.upper()
        if var not in STATUS_FIELDS:
            raise RobotiqError(f"unknown gripper status field {var!r}; the 2F-85 reports "
                               f"{', '.join(STATUS_FIELDS)}")
        return self.ReadStatus()[var]

    # ---- operations (those of RobotiqClient) -------------------------------
    def IsActive(self) -> bool:
        return self.Get("STA") == STA_ACTIVE

    def Activate(self, timeout: float | None = None, poll: float = 0.05) -> None:
        """Activates the gripper unless it is active without a fault (a reset
        and activation opens and closes an inactive 2F-85 once and clears a
        fault). Raises RobotiqError if it is not active within ``timeout``
        (default ``activation_timeout``), RobotiqFault if a fault remains."""
        timeout = self.config.activation_timeout if timeout is None else timeout
        status = self.ReadStatus(check_fault=False)
        if status["STA"] == STA_ACTIVE and status["FLT"] in NOT_AN_ABORT:
            return
        self.Set(ACT=0, GTO=0, ATR=0, ADR=0)
        self.Set(ACT=1)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.ReadStatus(check_fault=False)["STA"] == STA_ACTIVE:
                self.ReadStatus()          # a fault that the activation did not clear
                return
            time.sleep(poll)
        raise RobotiqError(f"the gripper on {self.where} did not become active (STA 3) within "
                           f"{timeout} s")

    def MoveToPos(self, pos: int) -> None:
        """Requests ``pos`` with the configured speed and force, and GTO 1,
        after a status read: a gripper in fault gets no request
        (RobotiqFault)."""
        pos = int(min(max(int(pos), 0), 255))
        self.ReadStatus()
        self.Set(POS=pos, SPE=self.config.speed, FOR=self.config.force, GTO=1)
        self.last_pos_sent = pos

    def Measure(self) -> tuple[float, int]:
        """(opening m, OBJ) from one status read: both of the same instant."""
        status = self.ReadStatus()
        return PosToOpening(status["POS"], self.config), status["OBJ"]

    def Status(self) -> int:
        return self.Get("STA")

    def Fault(self) -> int:
        """gFLT (0: none), without raising on it."""
        return self.ReadStatus(check_fault=False)["FLT"]

    def Close(self) -> None:
        """Closes the serial device; sends the gripper nothing (it stays as it is)."""
        modbus, self._modbus = self._modbus, None
        if modbus is not None:
            try:
                modbus.close()
            except Exception:  # noqa: BLE001 - closing a lost port
                pass
