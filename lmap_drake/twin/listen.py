"""Where the twin's servers may listen: servers that control a robot (the UR
emulator's dashboard, RTDE and script ports, the Robotiq socket, the camera
socket) have no authentication, so they bind to a loopback address unless
the caller says ``allow_remote`` (then a warning). Ports are 1..65535.
Checked as text, before any socket is made."""
from __future__ import annotations

import ipaddress


class ListenError(ValueError):
    """A host or port the twin's servers refuse to listen on."""


def ListenHostWarning(host: str, allow_remote: bool = False, option: str = "--host",
                      allow_option: str = "--allow_remote") -> str:
    """'' for a loopback ``host`` (127.0.0.0/8, ::1, ``localhost``); a
    warning for another address when ``allow_remote``; else ListenError."""
    text = str(host).strip()
    try:
        loopback = text == "localhost" or ipaddress.ip_address(text.strip("[]")).is_loopback
    except ValueError:
        loopback = False
    if loopback:
        return ""
    if not allow_remote:
        raise ListenError(
            f"{option} {host!r} is not a loopback address (127.x.y.z, ::1, localhost): the "
            f"servers that control the robot have no authentication and would be open to the "
            f"network; pass {allow_option} to listen there anyway")
    return (f"warning: listening on {host!r}, not loopback: anyone who reaches this address "
            f"can command the (emulated) robot")


def CheckPort(port, option: str) -> int:
    """``port`` as an int in 1..65535, else ListenError naming ``option``."""
    if isinstance(port, bool) or not isinstance(port, int) or not 1 <= port <= 65535:
        raise ListenError(f"{option} must be a TCP port in 1..65535, got {port!r}")
    return port
