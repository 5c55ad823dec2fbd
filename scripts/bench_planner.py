#!/usr/bin/env python3
"""Per-stage seconds of the LMAP planner on the default scenario, named as
in the paper's Table IV.

    python scripts/bench_planner.py --out bench_planner.json [--shapes ssc|oracle]
    python scripts/bench_planner.py --suite diagrams/suite.yaml --out bench_suite.json

The plant settles, camera0 is segmented (``perception.segmenter``), the
scene is completed (SSC with the trained DeepSDF, or ``--shapes oracle``:
the simulator's exact fruit and branch), then the planner runs the paper's
15 grasps x 14 directions x 4 distances. Writes
{"generation_collision_s", "deformation_s", "visibility_s", "total_s",
"num_candidates", "num_feasible", ...}. The benchmark is
``lmap_drake.studies.planner_benchmark``.
"""
import argparse
import json
import sys

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.studies.planner_benchmark import BenchDefault, BenchSuite


def main(argv=None) -> None:
    p = OneLineArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True)
    p.add_argument("--scenario_name", default="Defaults")
    p.add_argument("--suite", default="",
                   help="a suite YAML (e.g. diagrams/suite.yaml): plan once in every scene; "
                        "writes per-scene results and the median of each stage")
    p.add_argument("--shapes", choices=["ssc", "oracle"], default="ssc")
    a = p.parse_args(argv)
    out = BenchSuite(a.suite, a.shapes) if a.suite else BenchDefault(a.scenario_name, a.shapes)
    with open(a.out, "w") as f:
        json.dump(out, f, indent=2)
    print(json.dumps(out if not a.suite else {k: out[k] for k in
                                              ("median", "max_total_s", "num_scenes")},
                     indent=2))


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="bench_planner.py", strip_debug=True))  # one-line errors; --debug
