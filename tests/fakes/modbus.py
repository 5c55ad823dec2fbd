"""FAKE Robotiq 2F-85 on a Modbus RTU line, for the tests (under tests/: not
part of the product). Nothing here talks to a real gripper.

``FakeModbusGripperServer`` is a real pymodbus ``ModbusSerialServer`` (RTU
framing, slave 9 unless told) serving the 2F-85's registers over the
project's fake gripper model (``fakes.hardware.FakeGripper``: activation
delay, finite finger speed, fingers that stall on an object): writes to
0x03E8..0x03EA become the gripper's request, reads of 0x07D0..0x07D2 report
its status, both encoded here from the 2F-85 manual's byte layout
(independently of the client's own encoding).

The line is a pair of pseudo-terminals (``os.openpty``): the server opens
one pty's slave device, the client opens the other's (``device``), and a
relay thread copies bytes between the two masters, as a null-modem cable or
``socat`` would (socat is not installed here, and one pty alone cannot be
opened from both ends by path). pyserial opens a pty like any serial
device; the baud rate only matters to pymodbus's frame timing.

Faults to inject: ``Unplug()`` stops the relay (a pulled cable: requests
get no reply), ``Stop()`` stops the server (the gripper went silent),
``gripper.regs["FLT"] = 0x0E`` a gripper fault (cleared by a reset, rACT 0,
as on the real gripper). ``received`` lists (function code, address,
values) of every request the server decoded, ``wire`` the raw bytes the
client sent.
"""
from __future__ import annotations

import asyncio
import os
import select
import threading
import tty

from pymodbus.server import ModbusSerialServer
from pymodbus.simulator import DataType, SimData, SimDevice

from fakes.hardware import FakeGripper

REQUEST, STATUS = 0x03E8, 0x07D0


def _Pty() -> tuple[int, int, str]:
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    return master, slave, os.ttyname(slave)


class FakeModbusGripperServer:
    """FAKE 2F-85 Modbus RTU slave on a pty pair; ``device`` is the path the
    client opens. Use as a context manager (or ``Start`` / ``Stop``)."""

    def __init__(self, gripper: FakeGripper | None = None, slave_id: int = 9,
                 baud: int = 115200):
        self.gripper = gripper or FakeGripper()
        self.slave_id = slave_id
        self.baud = baud
        self.received: list[tuple[int, int, list[int] | None]] = []
        self.wire = bytearray()      # every byte the client sent, as on the line
        self._client_master, self._client_slave, self.device = _Pty()
        self._server_master, self._server_slave, self._server_device = _Pty()
        self._relaying = True
        self._closed = False
        self._relay = threading.Thread(target=self._Relay, daemon=True)
        self._loop = asyncio.new_event_loop()
        self._server = None
        self._listening = threading.Event()
        self._serve_error: BaseException | None = None
        self._thread = threading.Thread(target=self._Serve, daemon=True)

    # ---- the register map (2F-85 manual: high byte first) ------------------
    async def _Action(self, fc, start, address, count, registers, values):
        self.received.append((fc, address, list(values) if values else None))
        g = self.gripper
        if values and address == REQUEST and len(values) == 3:
            action = values[0] >> 8
            request = {"ACT": action & 1, "GTO": action >> 3 & 1, "ATR": action >> 4 & 1,
                       "ADR": action >> 5 & 1, "POS": values[1] & 0xFF,
                       "SPE": values[2] >> 8, "FOR": values[2] & 0xFF}
            if request["ACT"] == 0:
                g.regs["FLT"] = 0                    # a reset clears a fault
            g.Set(request)
        elif values is None and address == STATUS:
            r = {k: g.Get(k) for k in ("ACT", "GTO", "STA", "OBJ", "FLT", "PRE", "POS")}
            moving = r["OBJ"] == 0 and r["GTO"] == 1
            status = r["ACT"] | r["GTO"] << 3 | r["STA"] << 4 | r["OBJ"] << 6
            base = STATUS - start
            registers[base] = status << 8
            registers[base + 1] = (r["FLT"] & 0x0F) << 8 | r["PRE"]
            registers[base + 2] = r["POS"] << 8 | (25 if moving else 0)   # current, x 10 mA
        return None

    # ---- threads -----------------------------------------------------------
    def _Relay(self) -> None:
        a, b = self._client_master, self._server_master
        while not self._closed:
            try:
                ready, _, _ = select.select([a, b], [], [], 0.05)
                for fd in ready:
                    data = os.read(fd, 4096)
                    if self._relaying:                 # unplugged: the bytes are lost
                        if fd == a:
                            self.wire.extend(data)
                        os.write(b if fd == a else a, data)
            except OSError:
                return

    def _Serve(self) -> None:
        asyncio.set_event_loop(self._loop)

        async def main():
            device = SimDevice(self.slave_id, simdata=[
                SimData(REQUEST, count=3, values=0, datatype=DataType.REGISTERS),
                SimData(STATUS, count=3, values=0, datatype=DataType.REGISTERS)],
                action=self._Action)
            self._server = ModbusSerialServer(device, port=self._server_device,
                                              baudrate=self.baud)
            await self._server.serve_forever(background=True)
            self._listening.set()
            await self._server.serving
        try:
            self._loop.run_until_complete(main())
        except BaseException as err:  # noqa: BLE001 - reported by Start
            self._serve_error = err
            self._listening.set()

    def Start(self) -> "FakeModbusGripperServer":
        self._relay.start()
        self._thread.start()
        if not self._listening.wait(5.0) or self._serve_error is not None:
            raise RuntimeError(f"fake Modbus server did not start: {self._serve_error}")
        return self

    def Unplug(self) -> None:
        """The cable is pulled: nothing reaches the gripper or comes back."""
        self._relaying = False

    def Stop(self) -> None:
        """Stops the server (the gripper goes silent); the pty stays."""
        if self._server is not None and self._loop.is_running():
            asyncio.run_coroutine_threadsafe(self._server.shutdown(), self._loop).result(5.0)
        self._thread.join(5.0)

    def Close(self) -> None:
        self.Stop()
        self._closed = True
        self._relay.join(1.0)
        for fd in (self._client_master, self._client_slave, self._server_master,
                   self._server_slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self):
        return self.Start()

    def __exit__(self, *exc):
        self.Close()

    @property
    def writes(self) -> list[list[int]]:
        """The register values of every write to 0x03E8."""
        return [v for fc, a, v in self.received if fc == 16 and a == REQUEST]
