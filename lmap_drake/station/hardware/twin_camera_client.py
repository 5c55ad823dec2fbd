"""The hardware station's client of a camera over a local socket, for the
digital twin (``lmap-drake twin``): NOT a RealSense. The twin process renders
the simulated plant world and serves its frames
(``lmap_drake.twin.camera_server``); this client reads them in place of a
RealSense when ``hardware.camera.twin_address`` is set ("host:port").

Protocol (TCP, one request per line, ASCII):

- ``INFO`` -> one JSON line: ``width``, ``height``, ``fx``, ``fy``, ``cx``,
  ``cy`` (pixels), ``serial``, ``depth_scale`` (m per raw unit, NaN: none),
  ``time_scale`` (station seconds per wall second the twin runs at).
- ``FRAME`` -> one JSON line (``width``, ``height``, ``t``: the twin's time
  of the frame), then ``width*height*4`` bytes of RGBA and
  ``width*height*4`` bytes of float32 depth (metres, little-endian, inf =
  no return).
- anything else -> ``ERR <message>``.
"""
from __future__ import annotations

import json
import socket

import numpy as np
from pydrake.systems.sensors import CameraInfo

from lmap_drake.errors import HardwareStationUnavailable
from lmap_drake.station.hardware.safety import HardwareAbort


def ParseAddress(address: str) -> tuple[str, int]:
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(f"hardware.camera.twin_address must be 'host:port', got {address!r}")
    return host, int(port)


class TwinCameraClient:
    """The RealSenseClient interface (``CameraInfo``, ``Capture``,
    ``serial``, ``depth_scale``, ``Close``) over a twin camera server."""

    def __init__(self, address: str, timeout: float = 10.0):
        self.address = address
        host, port = ParseAddress(address)
        try:
            self._sock = socket.create_connection((host, port), timeout=timeout)
        except OSError as err:
            raise HardwareStationUnavailable(
                f"hardware station: no digital-twin camera at {address} ({err}); start the "
                f"twin first (lmap-drake twin)") from err
        self._file = self._sock.makefile("rb")
        self.info = json.loads(self._Request("INFO"))
        self.serial = str(self.info.get("serial", "twin"))
        self.depth_scale = float(self.info.get("depth_scale", float("nan")))
        self.time_scale = float(self.info.get("time_scale", 1.0))
        self._closed = False

    def _Request(self, line: str) -> str:
        try:
            self._sock.sendall((line + "\n").encode())
            reply = self._file.readline().decode()
        except OSError as err:
            raise HardwareAbort(f"hardware episode aborted: lost the twin camera at "
                                f"{self.address} ({err})") from err
        if not reply:
            raise HardwareAbort(f"hardware episode aborted: the twin camera at {self.address} "
                                f"closed the connection")
        if reply.startswith("ERR"):
            raise HardwareAbort(f"twin camera at {self.address}: {reply.strip()}")
        return reply

    def CameraInfo(self) -> CameraInfo:
        i = self.info
        return CameraInfo(int(i["width"]), int(i["height"]), float(i["fx"]), float(i["fy"]),
                          float(i["cx"]), float(i["cy"]))

    def Capture(self) -> tuple[np.ndarray, np.ndarray]:
        """(rgba HxWx4 uint8, depth HxW float32 metres, +inf = no return)."""
        head = json.loads(self._Request("FRAME"))
        w, h = int(head["width"]), int(head["height"])
        data = self._file.read(w * h * 8)
        if len(data) != w * h * 8:
            raise HardwareAbort(f"hardware episode aborted: short frame from the twin camera "
                                f"at {self.address}")
        rgba = np.frombuffer(data[:w * h * 4], np.uint8).reshape(h, w, 4).copy()
        depth = np.frombuffer(data[w * h * 4:], "<f4").reshape(h, w).astype(np.float32)
        return rgba, depth

    def Close(self) -> None:
        if not self._closed:
            self._closed = True
            try:
                self._sock.close()
            except OSError:
                pass
