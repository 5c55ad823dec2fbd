"""Which fruits perception finds in a plant's first view, and at what
thresholds: every plant of the scenario files is rendered (camera0, arm at
its start pose), segmented (``perception.segmenter``, default segnet),
de-projected into 3D fruit instances for each DBSCAN ``min_points`` value,
and each instance matched to the true fruit meshes (an instance is on a
fruit when at least half its points lie within ``--on_fruit`` of that
fruit's surface; otherwise it is a phantom). For each (DBSCAN
``min_points``, smallest instance the planner takes) pair it counts the
instances kept, the true fruits seen and the phantoms.

    python scripts/eval_fruit_detection.py --scenario_file diagrams/multi_suite.yaml \\
        --out out/fruit_detection.json

The study is ``lmap_drake.studies.fruit_detection`` (the JSON it writes,
why the planner's thresholds are what they are).
"""
from __future__ import annotations

import argparse
import sys

from lmap_drake.errors import InputError, OneLineArgumentParser
from lmap_drake.studies.fruit_detection import EvalFruitDetection


def main(argv=None) -> int:
    ap = OneLineArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario_file", nargs="+", required=True, help="scenario YAML(s)")
    ap.add_argument("--scenario_names", nargs="*", help="only these scenarios")
    ap.add_argument("--dbscan_min_points", nargs="+", type=int, default=[30, 15, 8])
    ap.add_argument("--min_instance_points", nargs="+", type=int, default=[30, 20, 15, 10])
    ap.add_argument("--on_fruit", type=float, default=0.006,
                    help="m: a point within this of a fruit's surface is on it")
    ap.add_argument("--settle", type=float, default=0.3,
                    help="simulated seconds before rendering (the FEM leaves settle)")
    ap.add_argument("--out", required=True, help="output JSON file")
    args = ap.parse_args(argv)
    try:
        EvalFruitDetection(**vars(args))
    except InputError as err:
        print(f"eval_fruit_detection: error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
