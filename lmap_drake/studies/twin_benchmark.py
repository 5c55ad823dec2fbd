"""The digital twin's pace while it holds the leaf (behind
``scripts/bench_twin.py``): CPU seconds per simulated second and the pace
(simulated s per wall s) of the twin's own loop (``Twin.RunPaced``: the
emulator exchange, the FEM step, the outcome samples, the frames), with
its servers up: the UR emulator in its child process (its CPU is measured
apart), the real camera socket read by the hardware station's
``TwinCameraClient`` at the run command's fps.

Per run: a new twin settles, the scenario's scripted approach closes the
gripper on the leaf and the twin makes its grasp (not timed); then the
timed part: a straight pull of ``plant_scene.pull`` over ``duration``
simulated s and a 0.5 s hold, the arm's command from that pull (a
SCRIPTED arm in place of the ur_rtde client's servo stream: the same
joints every run, so the variants differ only by the twin's settings).
Variants alternate run by run (A B A B ...), so that a change in the
machine's load falls on both.

``BenchTwinEpisodes``: whole episodes as a user runs them: ``lmap-drake
twin`` in a child process (optionally from another checkout, to compare
versions) and ``RunLmapEpisode(hardware=True)`` with the real ur_rtde
client; the twin's ``twin_log.json`` gives the pace and timing per phase.
"""
from __future__ import annotations

import json
import os
import platform
import random
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from lmap_drake.episode import RunLmapEpisode
from lmap_drake.paths import DEFAULT_SCENARIO_FILE
from lmap_drake.planning.motion import PlanPull, TimeJointPath
from lmap_drake.plants.scripted import ApproachAndGrasp
from lmap_drake.scenario import LoadScenario
from lmap_drake.station.hardware.twin_camera_client import TwinCameraClient
from lmap_drake.twin.twin import Twin, TwinOptions, TwinRunOverrides

HOLD = 0.5          # s held still after the pull (the episode observes there)


class _ScriptedPullTwin(Twin):
    """The twin with its arm command from a scripted pull (``traj``)
    instead of the emulator's servo joints; everything else is the twin's."""
    traj = None
    step = 0.02

    def _ArmCommand(self) -> np.ndarray:
        t = min(self.world.time + self.step, self.traj.end_time())
        return self.traj.value(t).ravel()


def _FreeHost(ports=(29999, 30003, 30004, 63352, 50410)) -> str:
    for n in random.sample(range(20, 250), 40):
        host = f"127.0.0.{n}"
        try:
            for port in ports:
                with socket.socket() as s:
                    s.bind((host, port))
            return host
        except OSError:
            continue
    raise RuntimeError("no loopback address with the twin's ports free")


def _ChildCpu(pid: int) -> float:
    """CPU seconds (user + system) of process ``pid`` so far (Linux)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return float("nan")


def _Loads() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def RunHeldOnce(scenario, options: dict, duration: float, fps: float = 5.0,
                progress=print) -> dict:
    """One timed held phase (see the module docstring) with the twin's
    ``options`` (``TwinOptions`` fields). Returns the held phase's timing
    (wall s by kind, ``cpu_s``), the pace, the emulator's CPU, the outcome
    measures of the timed part and the load."""
    o = TwinOptions(host=_FreeHost(), rate=1.0, **options)
    twin = _ScriptedPullTwin(scenario, o, progress=lambda m: None)
    stop = threading.Event()
    camera = thread = None
    try:
        twin.Start()
        w = twin.world
        ApproachAndGrasp(w, scenario.plant_scene.pull)
        twin._grasp_opening, twin._grasp_tcp = w.GripperWidth(), w.X_WT().translation()
        twin.gripper.holding = True
        pull = scenario.plant_scene.pull
        d = np.asarray(pull.direction_W, float)
        path = PlanPull(w.robot, w.X_WT(), pull.distance * d / np.linalg.norm(d), w.q_cmd)
        twin.traj = TimeJointPath(w.time, w.q_cmd, path, 0.5, 0.01, duration)
        t_end = twin.traj.end_time() + HOLD
        n_samples = len(w.samples)
        camera = TwinCameraClient(f"{o.host}:{o.camera_port}")
        emu_pid = twin.emulator.proc.proc.pid
        emu_cpu0, load0 = _ChildCpu(emu_pid), _Loads()
        thread = threading.Thread(target=twin.RunPaced, args=(stop,), daemon=True)
        thread.start()
        frames = 0
        while w.time < t_end - 1e-9 and thread.is_alive():
            t_next = time.monotonic() + 1.0 / fps      # the station's clock: rate 1
            camera.Capture()
            frames += 1
            time.sleep(max(0.0, t_next - time.monotonic()))
        stop.set()
        thread.join(timeout=60)
        emu_cpu = _ChildCpu(emu_pid) - emu_cpu0
        held = dict(twin.timing["held"])
        samples = w.samples[n_samples:]
    finally:
        stop.set()
        if camera is not None:
            camera.Close()
        twin.Close()
    sim = held["simulated_s"]
    wall = sum(held[k] for k in ("advance", "render", "other", "idle"))
    return {"simulated_s": sim, "wall_s": wall,
            "pace": sim / wall if wall > 0 else float("nan"),
            "cpu_per_sim_s": held["cpu_s"] / sim,
            "wall_per_sim_s": {k: held[k] / sim for k in ("advance", "render", "other", "idle")},
            "emulator_cpu_per_sim_s": emu_cpu / sim,
            "frames_requested": frames, "frames_rendered": sum(
                1 for f in twin.frames if f["t"] > t_end - HOLD - duration - 1e-9),
            "samples": len(samples),
            "max_petiole_force": max((s.petiole_force for s in samples), default=0.0),
            "max_strain": max((s.strain_percentile for s in samples), default=0.0),
            "p_WT_end": twin.world.X_WT().translation().tolist(),
            "load_before": load0, "load_after": _Loads()}


def BenchTwinHeld(variants: dict[str, dict], repeats: int = 3, duration: float = 2.0,
                  scenario_name: str = "Defaults", scenario_file=DEFAULT_SCENARIO_FILE,
                  progress=print) -> dict:
    """Runs every variant (name -> ``TwinOptions`` fields) ``repeats``
    times, alternating; returns each run and per variant the medians of
    ``cpu_per_sim_s``, ``pace`` and the outcome measures."""
    scenarios = {name: LoadScenario(filename=scenario_file, scenario_name=scenario_name,
                                    scenario_text=opts.get("scenario_text", "{}"))
                 for name, opts in variants.items()}
    runs = []
    for r in range(repeats):
        for name, opts in variants.items():
            progress(f"[bench_twin] run {r + 1}/{repeats}: {name}")
            options = {k: v for k, v in opts.items() if k != "scenario_text"}
            run = RunHeldOnce(scenarios[name], options, duration, progress=progress)
            run["variant"] = name
            runs.append(run)
            progress(f"[bench_twin]   cpu/sim s {run['cpu_per_sim_s']:.2f}, pace "
                     f"{run['pace']:.2f}x, load {run['load_before']}")
    summary = {}
    for name in variants:
        mine = [r for r in runs if r["variant"] == name]
        summary[name] = {k: statistics.median(r[k] for r in mine) for k in (
            "cpu_per_sim_s", "pace", "emulator_cpu_per_sim_s", "max_petiole_force",
            "max_strain")}
        summary[name]["options"] = variants[name]
    return {"summary": summary, "runs": runs, "repeats": repeats, "pull_duration_s": duration,
            "hold_s": HOLD, "scenario": f"{scenario_file}:{scenario_name}",
            "machine": f"{platform.machine()}, {os.cpu_count()} cpus"}


# The twin's settings compared (TwinOptions fields; ``scenario_text``: YAML
# overrides of the scenario). "before": a frame at most every 0.2 simulated
# s whether the arm moves or not, a ground-truth sample every 0.02 s twin
# step and the scenario's FEM threads (DefaultWorkers: 2 here), the twin's
# settings before the pace work; "after": the defaults.
VARIANTS = {"before": {"moving_frame_period": 0.2, "sample_period": 0.02, "fem_threads": 0},
            "after": {},
            "after_fem_threads_2": {"fem_threads": 2}}


def RunEpisodeOnce(out: Path, rate: float = 1.0, twin_code: str = "",
                   run_text: str = "{hardware: {ur: {joint_speed_limit: 3.0}}}") -> dict:
    """One episode against ``lmap-drake twin --rate rate`` (``twin_code``: a
    checkout whose ``lmap_drake`` the twin imports; "": this one). Returns
    the twin's ``pace``, ``max_lag_s``, ``timing``, the episode's status
    and the load."""
    host = _FreeHost()
    env, cwd = dict(os.environ), None
    if twin_code:      # (python -m puts the working folder first on the path)
        cwd = str(Path(twin_code).resolve())
        env["PYTHONPATH"] = cwd
    proc = subprocess.Popen([sys.executable, "-m", "lmap_drake.cli", "twin", "--host", host,
                             "--rate", str(rate), "--output", str(out.resolve() / "twin"),
                             "--duration", "900"], env=env, cwd=cwd, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    load0 = _Loads()
    try:
        for line in proc.stdout:
            if "lmap-drake run --hardware" in line:
                break
        else:
            raise RuntimeError("the twin did not start")
        text = TwinRunOverrides(TwinOptions(host=host), str(out / "twin" / "calibration.yaml"))
        scenario = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="Defaults",
                                scenario_text=[text, run_text])
        _, status = RunLmapEpisode(scenario, out / "run", progress=lambda m: None,
                                   hardware=True)
    finally:
        if proc.poll() is None:
            proc.stdin.write("quit\n")
            proc.stdin.flush()
        proc.communicate(timeout=300)
    log = json.loads((out / "twin" / "twin_log.json").read_text())
    timing = log["timing"]
    pace = {p: timing[p]["simulated_s"] / max(1e-9, sum(
        timing[p].get(k, 0.0) for k in ("advance", "render", "other", "idle")))
        for p in timing}
    return {"status": status, "pace": log["pace"], "pace_by_phase": pace,
            "max_lag_s": log["max_lag_s"], "timing": timing, "twin_code": twin_code or ".",
            "events": [e["event"] for e in log["events"]],
            "load_before": load0, "load_after": _Loads()}


def BenchTwinEpisodes(codes: dict[str, str], repeats: int = 3, rate: float = 1.0,
                      progress=print) -> dict:
    """Episodes against the twin of each checkout in ``codes`` (name ->
    folder, "": this one), alternating; per name the medians of the held
    and free phases' pace (simulated s per wall s, ``rate`` 1: the twin
    never waits for its clock while it lags)."""
    runs = []
    with tempfile.TemporaryDirectory(prefix="bench_twin_") as tmp:
        for r in range(repeats):
            for name, code in codes.items():
                progress(f"[bench_twin] episode {r + 1}/{repeats}: {name}")
                run = RunEpisodeOnce(Path(tmp) / f"{name}{r}", rate, code)
                run["variant"] = name
                runs.append(run)
                progress(f"[bench_twin]   {run['status']}, held pace "
                         f"{run['pace_by_phase']['held']:.2f}x, free "
                         f"{run['pace_by_phase']['free']:.2f}x, load {run['load_before']}")
    summary = {name: {f"{p}_pace": statistics.median(
        r["pace_by_phase"][p] for r in runs if r["variant"] == name) for p in ("held", "free")}
        for name in codes}
    return {"summary": summary, "runs": runs, "rate": rate, "repeats": repeats,
            "machine": f"{platform.machine()}, {os.cpu_count()} cpus"}
