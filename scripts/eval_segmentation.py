#!/usr/bin/env python
"""Segmentation IoU per backend and scenario against the simulator's labels.

    python scripts/eval_segmentation.py --out out/seg.json
    python scripts/eval_segmentation.py --scenario_file diagrams/default.yaml \
        --scenario_names Defaults OneOfEverything --backends color_depth label --out seg.json
    python scripts/eval_segmentation.py --scenarios 30 --seed 21 --out seg_random.json

The study is ``lmap_drake.studies.segmentation`` (images, default
scenarios, the JSON it writes).
"""
from __future__ import annotations

import sys
from pathlib import Path

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.paths import REPO_ROOT
from lmap_drake.studies.segmentation import DefaultScenarios, EvalSegmentation


def main(argv=None) -> int:
    file_default, _ = DefaultScenarios()
    ap = OneLineArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="output JSON file")
    ap.add_argument("--scenario_file", type=Path, default=None,
                    help=f"scenario YAML (default {file_default.relative_to(REPO_ROOT)})")
    ap.add_argument("--scenario_names", nargs="*", default=None,
                    help="scenario names (default: every scenario in suite.yaml, or "
                         "Defaults OneOfEverything in default.yaml)")
    ap.add_argument("--backends", nargs="+", default=["segnet", "color_depth", "label"])
    ap.add_argument("--scenarios", type=int, default=0,
                    help="evaluate RandomSuite(N, --seed) instead of a scenario file")
    ap.add_argument("--seed", type=int, default=0, help="RandomSuite seed")
    ap.add_argument("--scenario_text", default="{}", help="YAML overrides for every scenario")
    ap.add_argument("--settle", type=float, default=0.0,
                    help="simulated seconds before rendering (e.g. for a FEM leaf to settle)")
    args = ap.parse_args(argv)
    if args.scenarios < 0:
        ap.error("--scenarios must be >= 0")
    EvalSegmentation(**vars(args))
    return 0


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="eval_segmentation.py", strip_debug=True))  # one-line errors; --debug
