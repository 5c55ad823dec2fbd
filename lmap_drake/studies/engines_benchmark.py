"""Times ``lmap-drake eval`` on the process pool against Ray for the same
episodes, checks both give the same records, and measures the per-episode
cost behind ``evaluation.progress.EPISODE_CORE_SECONDS`` (the study behind
``scripts/bench_engines.py``; that script's help says what the JSON holds).

Each repeat runs the whole command (a fresh process: imports, workers or a
local Ray instance, the episodes, the tables) once per engine, in
alternating order (pool first on even repeats), and times it from the
outside. Records are compared without their timings
(``tables.Deterministic``), across engines and repeats.
"""
from __future__ import annotations

import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from lmap_drake.evaluation import tables as T

SCENES = ("small_leaf_thin_branch_round_red_heavy,small_leaf_thin_branch_round_red_partial,"
          "large_leaf_thick_branch_round_red_heavy,large_leaf_thick_branch_round_red_partial")
PLAN_EPISODES = 1000
PLAN_CORES = (2, 16, 64, 256)


def RunOnce(engine: str, eval_args: list[str], out: Path, log: Path) -> dict:
    """One whole ``lmap-drake eval`` process; wall and CPU seconds (CPU of
    the reaped descendants: the pool's workers, not Ray's, whose workers
    belong to its raylet)."""
    cmd = [sys.executable, "-m", "lmap_drake.cli", "eval", "--engine", engine,
           "--output", str(out)] + eval_args
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    with open(log, "w") as f:
        code = subprocess.call(cmd, stdout=f, stderr=subprocess.STDOUT)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return {"engine": engine, "wall_seconds": wall, "cpu_seconds_reaped": cpu,
            "exit_code": code, "output": str(out)}


def EvalRecords(out: Path) -> dict[str, dict]:
    """episode_id -> record of an eval output folder."""
    return {r["eval"]["episode_id"]: r for r in T.ReadRecords(out / "episodes.jsonl")}


def Differences(a: dict[str, dict], b: dict[str, dict]) -> list[str]:
    """'episode: field' for every deterministic field that differs (and
    episodes missing on one side)."""
    out = [f"{k}: missing" for k in sorted(set(a) ^ set(b))]
    for k in sorted(set(a) & set(b)):
        da, db = T.Deterministic(a[k]), T.Deterministic(b[k])
        for f in sorted(set(da) | set(db)):
            if json.dumps(da.get(f), sort_keys=True) != json.dumps(db.get(f), sort_keys=True):
                out.append(f"{k}: {f}")
    return out


def Costs(records: list[dict]) -> dict[str, dict]:
    """method -> median / min / max of ``cpu_seconds`` and ``wall_seconds``."""
    by: dict[str, dict[str, list[float]]] = {}
    for r in records:
        if r.get("status") == "error":
            continue
        d = by.setdefault(r["eval"]["method"], {"cpu_seconds": [], "wall_seconds": []})
        for k in d:
            if r.get(k):
                d[k].append(float(r[k]))
    return {m: {k: {"median": statistics.median(v), "min": min(v), "max": max(v), "n": len(v)}
                for k, v in d.items() if v} for m, d in by.items()}


def Plan(costs: dict[str, dict]) -> dict:
    """1,000 episodes of each measured method at its median CPU seconds:
    core-hours, and wall hours on ``PLAN_CORES`` cores (no overhead; an
    episode is one core's work)."""
    out = {}
    for m, c in costs.items():
        sec = (c.get("cpu_seconds") or c["wall_seconds"])["median"]
        out[m] = {"episodes": PLAN_EPISODES, "seconds_per_episode": sec,
                  "core_hours": PLAN_EPISODES * sec / 3600.0,
                  "wall_hours_on_cores": {str(n): PLAN_EPISODES * sec / 3600.0 / n
                                          for n in PLAN_CORES}}
    return out


def Analyse(runs: list[dict], repeats: int, eval_args: list[str]) -> dict:
    """Everything the JSON says, from the runs and the records they left."""
    records = {(r["engine"], r["repeat"]): EvalRecords(Path(r["output"])) for r in runs}
    wall = {e: statistics.median(r["wall_seconds"] for r in runs if r["engine"] == e)
            for e in ("pool", "ray")}

    def at(engine, k):
        return next(r["wall_seconds"] for r in runs if r["engine"] == engine and r["repeat"] == k)
    ratios = [at("ray", k) / at("pool", k) for k in range(repeats)]
    ref = records[("pool", 0)]
    diffs = {f"{e}{k}": Differences(ref, recs) for (e, k), recs in records.items()
             if (e, k) != ("pool", 0)}
    cross = {k: v for k, v in diffs.items() if k.startswith("ray")}
    costs = Costs([r for recs in records.values() for r in recs.values()])
    return {
        "machine": {"cpus": os.cpu_count(), "load_average_at_end": os.getloadavg(),
                    "note": "a shared 2-core machine (another engineer's simulations and "
                            "tests ran at the same time; this benchmark ran under nice -n 10)"},
        "eval_args": eval_args, "episodes": len(ref), "repeats": repeats,
        "runs": runs, "wall_seconds_median": wall,
        "ray_over_pool_ratios": ratios, "ray_over_pool_median": statistics.median(ratios),
        "identical_records_ray_vs_pool": all(not v for v in cross.values()),
        "identical_records_all_runs": all(not v for v in diffs.values()),
        "differences_vs_pool0": diffs,
        "episode_cost_seconds": costs, "plan_1000_episodes": Plan(costs),
    }


def Reanalyse(previous: Path | str, out: Path | str) -> dict:
    """Recomputes all but the timings of a previous JSON of this benchmark
    from the outputs its run kept (``--keep``); writes ``out``."""
    old = json.loads(Path(previous).read_text())
    result = Analyse(old["runs"], old["repeats"], old["eval_args"])
    result["machine"]["load_average_at_end"] = old["machine"]["load_average_at_end"]
    Path(out).write_text(json.dumps(result, indent=2))
    return result


def BenchEngines(out: Path | str, repeats: int = 3, workers: int = 2,
                 scenario_names: str = SCENES, methods: str = "lmap,upward",
                 distances: str = "0.04", keep: str = "") -> dict:
    """``repeats`` x (pool, ray) runs of ``lmap-drake eval`` on the episodes
    given; their outputs in ``keep`` (or a temporary folder). Writes the
    analysis to ``out`` (JSON) and prints a progress line per run and the
    summary."""
    eval_args = ["--workers", str(workers), "--scenario_names", scenario_names,
                 "--methods", methods, "--distances", distances]
    root = Path(keep) if keep else Path(tempfile.mkdtemp(prefix="bench_engines-"))
    root.mkdir(parents=True, exist_ok=True)
    runs = []
    for rep in range(repeats):
        for engine in (("pool", "ray") if rep % 2 == 0 else ("ray", "pool")):
            run_out = root / f"{engine}{rep}"
            run = RunOnce(engine, eval_args, run_out, root / f"{engine}{rep}.log")
            run["repeat"] = rep
            runs.append(run)
            print(f"repeat {rep} {engine}: {run['wall_seconds']:.1f} s wall, exit "
                  f"{run['exit_code']}, {len(EvalRecords(run_out))} records", flush=True)
    result = Analyse(runs, repeats, eval_args)
    Path(out).write_text(json.dumps(result, indent=2))
    print(json.dumps({k: result[k] for k in ("wall_seconds_median", "ray_over_pool_median",
                                             "identical_records_ray_vs_pool",
                                             "identical_records_all_runs")}, indent=1))
    return result
