#!/usr/bin/env python3
"""Realtime factor of the simulated station during a pull.

    python scripts/bench_station.py --out bench_station.json
    python scripts/bench_station.py --out gh.json \
        --scenario_file diagrams/greenhouse_suite.yaml --scenario_name gh_one_red_heavy

Builds the default scenario (FEM leaf), approaches and grasps the leaf (not
timed), then times a 2 s pull of the default direction and distance:
``realtime_factor`` = wall seconds per simulated second (including the
ground-truth monitors sampled every ``outcome.sample_period``), and the same
for the bare simulator (``realtime_factor_simulation_only``, monitors off).
The benchmark is ``lmap_drake.studies.station_benchmark``.
"""
import argparse
import json
import sys

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.paths import DEFAULT_SCENARIO_FILE
from lmap_drake.studies.station_benchmark import BenchStation


def main(argv=None) -> None:
    p = OneLineArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True)
    p.add_argument("--scenario_name", default="Defaults")
    p.add_argument("--duration", type=float, default=2.0)
    p.add_argument("--scenario_file", default=str(DEFAULT_SCENARIO_FILE))
    p.add_argument("--leaf", type=int, default=-1,
                   help="the FEM leaf to grasp (multi / greenhouse plants; -1: the first "
                        "one the arm reaches)")
    p.add_argument("--scenario_text", default="{}", help="YAML overrides applied last")
    a = p.parse_args(argv)
    result = BenchStation(a.scenario_name, a.duration, a.scenario_file, a.leaf, a.scenario_text)
    with open(a.out, "w") as f:
        json.dump(result, f, indent=2)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="bench_station.py", strip_debug=True))  # one-line errors; --debug
