#!/usr/bin/env python
"""The deformation-graph predictor (paper Sec. III-B) against the FEM leaf.

    python scripts/eval_deformation_vs_fem.py --out out/deformation_vs_fem.json
    python scripts/eval_deformation_vs_fem.py --out d.json \
        --scenarios small_leaf_thin_branch_round_red_heavy --corr_scenarios

Per scenario (default: every scenario in diagrams/suite.yaml): the observed
leaf points deformed by the predictor against the same points carried by
the FEM leaf of the plant world, with baselines, and (``--corr_scenarios``)
Spearman correlations between the predicted energy and the FEM measures.
The study is ``lmap_drake.studies.deformation_vs_fem`` (the steps, the
workarounds, the JSON it writes). Exit code 1 when a scenario failed.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.studies.deformation_vs_fem import (DEFAULT_CORR, DeformationVsFemOptions,
                                                   RunDeformationVsFem)


def main(argv=None) -> int:
    d = DeformationVsFemOptions()
    p = OneLineArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", required=True)
    p.add_argument("--scenario_file", type=Path, default=d.scenario_file)
    p.add_argument("--scenarios", nargs="*", default=d.scenarios,
                   help="scenario names (default: every scenario in the file)")
    p.add_argument("--corr_scenarios", nargs="*", default=d.corr_scenarios,
                   help=f"scenarios that also run the correlation pulls (default: {DEFAULT_CORR} "
                        "when evaluated; give the flag with no names for none)")
    p.add_argument("--corr_directions", nargs="+", default=d.corr_directions,
                   choices=["scenario", "away", "lateral", "up"])
    p.add_argument("--corr_distances", nargs="+", type=float, default=d.corr_distances)
    p.add_argument("--distance", type=float, default=d.distance)
    p.add_argument("--direction", type=float, nargs=3, default=d.direction,
                   help="pull direction in W (default: each scenario's pull.direction_W)")
    p.add_argument("--speed", type=float, default=d.speed, help="pull speed (m/s)")
    p.add_argument("--hold", type=float, default=d.hold)
    p.add_argument("--settle", type=float, default=d.settle)
    p.add_argument("--segmenter", default=d.segmenter)
    p.add_argument("--grasp_fallbacks", nargs="+", type=float, default=d.grasp_fallbacks,
                   help="extra grasp_from_tip (m) tried in turn when the approach IK fails")
    p.add_argument("--scenario_text", default=d.scenario_text,
                   help="YAML overrides for every scenario")
    p.add_argument("--keep_degenerate_leaf_mesh", action="store_true",
                   help="do not re-mesh a leaf with a near-degenerate tet (see "
                        "LeafMeshWorkaround); such scenarios then usually fail")
    return RunDeformationVsFem(DeformationVsFemOptions(**vars(p.parse_args(argv))))


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="eval_deformation_vs_fem.py", strip_debug=True))  # one-line errors; --debug
