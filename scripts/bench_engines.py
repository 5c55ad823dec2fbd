#!/usr/bin/env python
"""Times ``lmap-drake eval`` on the process pool against Ray for the same
episodes, checks both give the same records, and measures the
per-episode cost behind ``progress.EPISODE_CORE_SECONDS`` and the sweep
plan in the README.

    python scripts/bench_engines.py --out bench_engines.json [--repeats 3] [--keep DIR]
    python scripts/bench_engines.py --out bench_engines.json --reanalyse bench_engines.json

Each repeat runs the whole command (a fresh process: imports, workers or
a local Ray instance, the episodes, the tables) once per engine, in
alternating order (pool first on even repeats), and times it from the
outside. Records are compared without their timings
(``tables.Deterministic``), across engines and repeats. Default episodes:
4 suite scenes x (lmap, upward at 4 cm) = 8, on 2 workers / 2 Ray CPUs.

Output JSON: each run's wall and CPU seconds, the medians per engine, the
median of the per-repeat ratios ray / pool, whether the records are
identical (and which fields differ), an episode's cost per method (median
``cpu_seconds``, its core-seconds; and ``wall_seconds``, which on a busy
machine is longer) and what 1,000 such episodes cost in core-hours and in
wall hours on 2 to 256 cores. ``--reanalyse`` recomputes all but the
timings from the outputs a kept run (``--keep``) left.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from lmap_drake.errors import RunMain
from lmap_drake.evaluation import tables as T

SCENES = ("small_leaf_thin_branch_round_red_heavy,small_leaf_thin_branch_round_red_partial,"
          "large_leaf_thick_branch_round_red_heavy,large_leaf_thick_branch_round_red_partial")
PLAN_EPISODES = 1000
PLAN_CORES = (2, 16, 64, 256)


def _RunOnce(engine: str, eval_args: list[str], out: Path, log: Path) -> dict:
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


def _Records(out: Path) -> dict[str, dict]:
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
    records = {(r["engine"], r["repeat"]): _Records(Path(r["output"])) for r in runs}
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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="JSON file to write")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--scenario_names", default=SCENES)
    ap.add_argument("--methods", default="lmap,upward")
    ap.add_argument("--distances", default="0.04")
    ap.add_argument("--keep", default="", help="keep the eval outputs in this folder")
    ap.add_argument("--reanalyse", default="",
                    help="a previous JSON of this script whose outputs were kept")
    args = ap.parse_args()
    if args.reanalyse:
        old = json.loads(Path(args.reanalyse).read_text())
        result = Analyse(old["runs"], old["repeats"], old["eval_args"])
        result["machine"]["load_average_at_end"] = old["machine"]["load_average_at_end"]
        Path(args.out).write_text(json.dumps(result, indent=2))
        return 0
    eval_args = ["--workers", str(args.workers), "--scenario_names", args.scenario_names,
                 "--methods", args.methods, "--distances", args.distances]
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="bench_engines-"))
    root.mkdir(parents=True, exist_ok=True)
    runs = []
    for rep in range(args.repeats):
        for engine in (("pool", "ray") if rep % 2 == 0 else ("ray", "pool")):
            out = root / f"{engine}{rep}"
            run = _RunOnce(engine, eval_args, out, root / f"{engine}{rep}.log")
            run["repeat"] = rep
            runs.append(run)
            print(f"repeat {rep} {engine}: {run['wall_seconds']:.1f} s wall, exit "
                  f"{run['exit_code']}, {len(_Records(out))} records", flush=True)
    result = Analyse(runs, args.repeats, eval_args)
    Path(args.out).write_text(json.dumps(result, indent=2))
    print(json.dumps({k: result[k] for k in ("wall_seconds_median", "ray_over_pool_median",
                                             "identical_records_ray_vs_pool",
                                             "identical_records_all_runs")}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(RunMain(main, prog="bench_engines", strip_debug=True))
