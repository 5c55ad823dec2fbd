"""The Robotiq 2F-85 URCap socket (port 63352) served over a register model:
the digital twin's gripper (``twin.gripper.TwinGripper``: the simulated fingers)
behind the protocol the hardware station's ``RobotiqClient`` speaks (ASCII
lines ``SET VAR value ...`` -> ``ack``, ``GET VAR`` -> ``VAR value``;
anything else -> ``?``). Not a gripper: nothing here moves one.
"""
from __future__ import annotations

import socket
import socketserver
import threading

from lmap_drake.twin.listen import ListenHostWarning


class _RobotiqHandler(socketserver.StreamRequestHandler):
    def handle(self):
        server = self.server
        with server.clients_lock:
            server.clients.append(self.request)
        for raw in self.rfile:
            line = raw.decode("ascii", errors="replace").strip()
            server.received.append(line)
            parts = line.split()
            reply = "?"  # the answer to malformed requests
            if len(parts) >= 3 and parts[0] == "SET" and len(parts) % 2 == 1:
                try:
                    values = {parts[i]: int(parts[i + 1]) for i in range(1, len(parts), 2)}
                    reply = "ack" if server.gripper.Set(values) else "?"
                except ValueError:
                    pass
            elif len(parts) == 2 and parts[0] == "GET":
                value = server.gripper.Get(parts[1])
                if value is not None:
                    reply = f"{parts[1]} {value}\n"
            if server.silent:
                continue
            self.wfile.write(reply.encode("ascii"))


class RobotiqSocketServer(socketserver.ThreadingTCPServer):
    """A Robotiq URCap socket server on ``host`` (default 127.0.0.1) and
    ``port`` (default an ephemeral one); ``gripper`` is any register model
    with ``Set(dict) -> bool`` and ``Get(name) -> int | None``.
    ``received`` lists every request line; ``silent`` stops replies;
    ``DropClients`` closes every connection (a lost link)."""
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, gripper, host: str = "127.0.0.1", port: int = 0,
                 allow_remote: bool = False):
        ListenHostWarning(host, allow_remote)     # loopback only unless allowed
        super().__init__((host, port), _RobotiqHandler)
        self.gripper = gripper
        self.received: list[str] = []
        self.silent = False
        self.clients = []
        self.clients_lock = threading.Lock()
        self._thread = threading.Thread(target=self.serve_forever, kwargs={"poll_interval": 0.02},
                                        daemon=True)

    @property
    def port(self) -> int:
        return self.server_address[1]

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self.shutdown()
        self.server_close()

    def DropClients(self) -> None:
        with self.clients_lock:
            for s in self.clients:
                try:
                    s.shutdown(socket.SHUT_RDWR)
                    s.close()
                except OSError:
                    pass
