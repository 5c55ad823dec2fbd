"""A SIGKILLed ``lmap-drake eval --engine ray`` leaves no process of the
local Ray instance it started: the reaper (``evaluation/ray_reaper.py``)
terminates the node's processes and their descendants (workers, agents)
within seconds (issue 61, defect 26)."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lmap_drake.evaluation.ray_reaper import Descendants, _StartTime

pytest.importorskip("ray")
pytestmark = [pytest.mark.skipif(not os.path.isdir("/proc"), reason="needs /proc (Linux)"),
              pytest.mark.realtime]      # 10 s after a SIGKILL: timed

ROOT = Path(__file__).resolve().parents[2]


def _Ray(eval_pid: int) -> dict[int, str]:
    """The eval's descendants (the Ray node and the reaper) with their
    start times."""
    return {pid: _StartTime(pid) for pid in Descendants([eval_pid]) - {eval_pid}}


def _Cmd(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def test_sigkilled_ray_eval_leaves_no_ray_process(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(
        [sys.executable, "-m", "lmap_drake.cli", "eval", "--engine", "ray", "--workers", "1",
         "--methods", "upward", "--distances", "0.04",
         "--scenario_names", "small_leaf_thin_branch_round_red_partial",
         "--output", str(tmp_path / "ev")],
        cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        seen: dict[int, str] = {}
        deadline = time.monotonic() + 90
        # Ray is up: its GCS, raylet and at least one worker or agent
        while time.monotonic() < deadline and proc.poll() is None:
            now = _Ray(proc.pid)
            seen.update(now)
            cmds = " ".join(_Cmd(p) for p in now)
            if all(k in cmds for k in ("ray_reaper.py", "raylet", "gcs_server", "ray::")):
                break
            time.sleep(0.3)
        assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
        assert seen and time.monotonic() < deadline, "Ray did not come up"
        time.sleep(1.0)                          # the reaper has recorded the node
        seen.update(_Ray(proc.pid))
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        end = time.monotonic() + 10
        while time.monotonic() < end:
            left = {p for p, s in seen.items() if _StartTime(p) == s}
            if not left:
                break
            time.sleep(0.2)
        assert not left, f"processes alive 10 s after SIGKILL: {sorted(left)}"
        assert len(seen) >= 5                    # GCS, raylet, agents, worker, the reaper
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_a_dead_process_not_yet_collected_counts_as_gone():
    """A zombie (exited, its parent has not waited for it; an orphan's
    parent is PID 1, which may collect it late) holds nothing: neither the
    reaper nor this test's check waits for it."""
    child = subprocess.Popen(["true"])
    try:
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            with open(f"/proc/{child.pid}/stat") as f:
                state = f.read().rsplit(")", 1)[1].split()[0]
            if state == "Z":
                break
            time.sleep(0.05)
        assert state == "Z"
        assert _StartTime(child.pid) is None
        assert _StartTime(os.getpid()) is not None
    finally:
        child.wait()
