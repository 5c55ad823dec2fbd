#!/usr/bin/env python
"""Does the planner's prediction rank petiole loading and strain as the FEM
plant world does, for straight pulls, hinge arcs and twists?

    python scripts/eval_hazard_prediction.py --out out/hazard.json
    python scripts/eval_hazard_prediction.py --out h.json \
        --scenarios small_leaf_thin_branch_round_red_heavy --pull_distances 0.04 0.08

Multi-fruit plants are studied from the grasps the planner itself chooses:

    python scripts/make_suite.py --multi --random 3 --seed 5151 --out out/rm.yaml
    python scripts/eval_hazard_prediction.py --out out/hazard_multi.json \
        --scenario_file out/rm.yaml --scenarios random_multi_5151_000 \
        --families pull --pull_distances 0.015 0.025 0.035 0.045

The study is ``lmap_drake.studies.hazard`` (the steps, the measures, the
JSON it writes after every scenario).
"""
from __future__ import annotations

import sys
from pathlib import Path

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.studies.hazard import HazardStudyOptions, RunHazardStudy


def main(argv=None) -> int:
    d = HazardStudyOptions()
    p = OneLineArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True)
    p.add_argument("--scenario_file", type=Path, default=d.scenario_file)
    p.add_argument("--scenarios", nargs="*", default=d.scenarios)
    p.add_argument("--pull_distances", nargs="+", type=float, default=d.pull_distances)
    p.add_argument("--arc_angles", nargs="+", type=float, default=d.arc_angles)
    p.add_argument("--twist_angles", nargs="+", type=float, default=d.twist_angles)
    p.add_argument("--families", nargs="+", default=d.families,
                   choices=["pull", "arc", "twist"],
                   help="action families to execute (e.g. only the twists, to pool with "
                        "an earlier run's pulls and arcs: --pool)")
    p.add_argument("--pool", nargs="*", default=d.pool,
                   help="earlier runs' JSON whose rows join the pooled correlations")
    p.add_argument("--num_axes", type=int, default=d.num_axes)
    p.add_argument("--then_twist", nargs="*", type=float, default=d.then_twist,
                   help="multi-fruit plants: after each arc, also continuation twists by "
                        "these angles (deg, both senses) from where the arc ends, as "
                        "re-planning makes them (rows of family 'arc+twist')")
    p.add_argument("--then_arc", nargs="*", type=float, default=d.then_arc,
                   help="likewise continuation arcs by these angles (deg) about --num_axes "
                        "axes (rows of family 'arc+arc')")
    p.add_argument("--then_turn_band", nargs=2, type=float, default=d.then_turn_band,
                   help="execute only the continuations whose equivalent turn from the "
                        "first grasp lies in (LO, HI] degrees")
    p.add_argument("--speed", type=float, default=d.speed, help="TCP speed (m/s)")
    p.add_argument("--hold", type=float, default=d.hold)
    p.add_argument("--segmenter", default=d.segmenter, help="default: the scenario's")
    p.add_argument("--repredict", action="store_true",
                   help="re-run only the predictions of --out (with --deformation_text); "
                        "writes OUT.repredicted.json")
    p.add_argument("--deformation_text", default=d.deformation_text)
    p.add_argument("--hinge_bending_weight", type=float, default=d.hinge_bending_weight,
                   help="with --repredict (default: the planner's)")
    return RunHazardStudy(HazardStudyOptions(**vars(p.parse_args(argv))))


if __name__ == "__main__":
    sys.exit(main())
