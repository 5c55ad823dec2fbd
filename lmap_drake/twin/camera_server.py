"""The digital twin's camera server: serves the frames the twin renders
from the simulated plant world over a local socket, in the protocol the
hardware station's ``TwinCameraClient`` reads
(``lmap_drake.station.hardware.twin_camera_client``, whose docstring has
the protocol).
"""
from __future__ import annotations

import json
import socketserver
import threading

import numpy as np

from lmap_drake.twin.listen import ListenHostWarning


class _Handler(socketserver.StreamRequestHandler):
    def handle(self):
        server: TwinCameraServer = self.server
        for raw in self.rfile:
            line = raw.decode("ascii", errors="replace").strip()
            try:
                if line == "INFO":
                    self.wfile.write((json.dumps(server.info) + "\n").encode())
                elif line == "FRAME":
                    t, rgba, depth = server.frame()
                    h, w = depth.shape
                    head = json.dumps({"width": w, "height": h, "t": float(t)}) + "\n"
                    self.wfile.write(head.encode() + np.ascontiguousarray(rgba, np.uint8)
                                     .tobytes() + np.ascontiguousarray(depth, "<f4").tobytes())
                else:
                    self.wfile.write(f"ERR unknown request {line[:40]!r}\n".encode())
            except (BrokenPipeError, ConnectionResetError):
                return
            except Exception as err:  # noqa: BLE001 - reported to the client
                self.wfile.write(f"ERR {type(err).__name__}: {err}\n".encode())


class TwinCameraServer(socketserver.ThreadingTCPServer):
    """Serves ``frame() -> (t, rgba HxWx4 uint8, depth HxW float32 m)`` and
    ``info`` (a dict, see the protocol in ``twin_camera_client``) on
    ``host:port`` (port 0: an ephemeral one, see ``port``)."""
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, info: dict, frame, host: str = "127.0.0.1", port: int = 0,
                 allow_remote: bool = False):
        ListenHostWarning(host, allow_remote)     # loopback only unless allowed
        super().__init__((host, port), _Handler)
        self.info, self.frame = dict(info), frame
        self._thread = threading.Thread(target=self.serve_forever,
                                        kwargs={"poll_interval": 0.05}, daemon=True)

    @property
    def port(self) -> int:
        return self.server_address[1]

    def Start(self) -> "TwinCameraServer":
        self._thread.start()
        return self

    def Close(self) -> None:
        self.shutdown()
        self.server_close()
