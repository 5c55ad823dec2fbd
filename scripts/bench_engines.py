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
timings from the outputs a kept run (``--keep``) left. The study is
``lmap_drake.studies.engines_benchmark``.
"""
from __future__ import annotations

import argparse
import sys

from lmap_drake.errors import OneLineArgumentParser, RunMain
from lmap_drake.studies.engines_benchmark import SCENES, BenchEngines, Reanalyse


def main(argv=None) -> int:
    ap = OneLineArgumentParser(description=__doc__,
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
    args = ap.parse_args(argv)
    if args.reanalyse:
        Reanalyse(args.reanalyse, args.out)
        return 0
    BenchEngines(args.out, args.repeats, args.workers, args.scenario_names, args.methods,
                 args.distances, args.keep)
    return 0


if __name__ == "__main__":
    sys.exit(RunMain(main, prog="bench_engines", strip_debug=True))
