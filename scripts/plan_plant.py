#!/usr/bin/env python3
"""Plans the reveal of every fruit of a plant from its first view, without
moving anything: what a multi-fruit episode would try for each fruit if
each were first in line.

    python scripts/plan_plant.py --scenario_file diagrams/multi_suite.yaml \
        --out plan_plant.json [--scenario_name NAME ...] [--shapes ssc|oracle]

The plant settles, camera0 is segmented (``perception.segmenter``), the
plant is completed (``CompletePlant``), and for every fruit instance the
planner runs as ``PlantPlanning`` would (``PlanTarget``: each occluding leaf,
the rest of the plant as obstacles). Writes, per scene and fruit: the
ground-truth fruit it matches (nearest centre) and that fruit's true
visibility, the predicted visibility, the occluding leaves, per leaf the
plan's status, the rejection reasons with counts and the chosen action.
The study is ``lmap_drake.studies.plant_plans``.
"""
import argparse
import sys

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.studies.plant_plans import PlanPlants


def main(argv=None) -> None:
    p = OneLineArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scenario_file", required=True)
    p.add_argument("--scenario_name", action="append", default=[],
                   help="scene(s) of the file (repeat; default: every scene)")
    p.add_argument("--scenario_text", default="", help="YAML override for every scene")
    p.add_argument("--out", required=True)
    a = p.parse_args(argv)
    PlanPlants(a.scenario_file, a.out, a.scenario_name, a.scenario_text)


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="plan_plant.py", strip_debug=True))
