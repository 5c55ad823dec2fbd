"""The reaper of a local Ray instance: a tiny process (stdlib only, run as
a script) started by ``RayEngine`` just before ``ray.init`` of a local
instance (never for a cluster at ``--address``). While the eval process
lives it records, every half second, all its descendants: the Ray node's
processes and theirs (workers and agents rename themselves, so ancestry is
what identifies them; a process reparented after its parent died stays
recorded), each with its start time
(so a reused pid is never touched). When the eval process is gone (however
it ended: SIGKILL included) it sends SIGTERM to every recorded process still
alive, SIGKILL to those left after two seconds, and exits.

Usage: ``python ray_reaper.py PARENT_PID``."""
from __future__ import annotations

import os
import signal
import sys
import time

POLL_S = 0.5
GRACE_S = 2.0


def _StartTime(pid: int) -> str | None:
    """The process's start time (``/proc/PID/stat`` field 22), None when gone
    or dead (a zombie: killed, its exit not yet collected by its parent,
    which for an orphan is PID 1; it holds nothing but its pid)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            stat = f.read()
    except OSError:
        return None
    fields = stat[stat.rfind(")") + 2:].split()
    return None if fields[0] in ("Z", "X") else fields[19]


def _Children() -> dict[int, list[int]]:
    """parent pid -> child pids, over every process."""
    out: dict[int, list[int]] = {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        ppid = int(stat[stat.rfind(")") + 2:].split()[1])
        out.setdefault(ppid, []).append(int(name))
    return out


def Descendants(roots) -> set[int]:
    """``roots`` and all their descendants now alive."""
    children = _Children()
    seen, todo = set(), [r for r in roots if _StartTime(r) is not None]
    while todo:
        pid = todo.pop()
        if pid in seen:
            continue
        seen.add(pid)
        todo.extend(children.get(pid, ()))
    return seen


def _Alive(recorded: dict[int, str]) -> list[int]:
    return [pid for pid, start in recorded.items() if _StartTime(pid) == start]


def Reap(recorded: dict[int, str], refresh=None) -> None:
    """SIGTERM, then after ``GRACE_S`` SIGKILL, to the recorded processes
    still alive (same pid and start time); ``refresh()`` before each (it
    may record what they spawned meanwhile: a node shutting down can)."""
    for sig, wait in ((signal.SIGTERM, GRACE_S), (signal.SIGKILL, 0.0)):
        if refresh is not None:
            refresh()
        for pid in _Alive(recorded):
            try:
                os.kill(pid, sig)
            except OSError:
                pass
        end = time.monotonic() + wait
        while time.monotonic() < end and _Alive(recorded):
            time.sleep(0.1)


def Watch(parent: int) -> None:
    """Records ``parent``'s descendants until it is gone, then reaps them."""
    recorded: dict[int, str] = {}
    roots = [parent]

    def record():
        for pid in Descendants(_Alive(recorded) + roots):
            start = _StartTime(pid)
            if start is not None and pid != os.getpid():
                recorded.setdefault(pid, start)
    parent_start = _StartTime(parent)
    while _StartTime(parent) == parent_start and parent_start is not None:
        record()
        time.sleep(POLL_S)
    roots = []
    record()            # what the node spawned since the last look
    recorded.pop(parent, None)
    Reap(recorded, record)


def main(argv: list[str]) -> int:
    signal.signal(signal.SIGINT, signal.SIG_IGN)    # a Ctrl-C is for the eval
    try:
        (parent,) = (int(a) for a in argv)
    except ValueError:
        return 2
    Watch(parent)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
