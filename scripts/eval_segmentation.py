#!/usr/bin/env python
"""Segmentation IoU per backend against the simulator's labels, on scenarios
rendered here or on recorded runs.

    python scripts/eval_segmentation.py --out out/seg.json
    python scripts/eval_segmentation.py --scenario_file diagrams/default.yaml \
        --scenario_names Defaults OneOfEverything --backends color_depth label --out seg.json
    python scripts/eval_segmentation.py --scenarios 30 --seed 21 --out seg_random.json
    python scripts/eval_segmentation.py --recordings out/ --backends segnet,color_depth \
        --out out/seg_recordings.json      # every out/*/recording/ with labels

The study is ``lmap_drake.studies.segmentation`` (images, default
scenarios, the JSON it writes, the pictures per recorded view).
"""
from __future__ import annotations

import sys
from pathlib import Path

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.paths import REPO_ROOT
from lmap_drake.perception.segmentation import SEGMENTERS
from lmap_drake.studies.segmentation import DefaultScenarios, EvalRecordings, EvalSegmentation


def main(argv=None) -> int:
    file_default, _ = DefaultScenarios()
    ap = OneLineArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="output JSON file")
    ap.add_argument("--recordings", type=Path, default=None,
                    help="evaluate every DIR/*/recording/ whose views carry labels "
                         "(view<k>_label.npy) instead of rendering scenarios; pictures per "
                         "view go to <out>_views/")
    ap.add_argument("--scenario_file", type=Path, default=None,
                    help=f"scenario YAML (default {file_default.relative_to(REPO_ROOT)})")
    ap.add_argument("--scenario_names", nargs="*", default=None,
                    help="scenario names (default: every scenario in suite.yaml, or "
                         "Defaults OneOfEverything in default.yaml)")
    ap.add_argument("--backends", nargs="+", default=["segnet", "color_depth", "label"],
                    help=f"segmenters, space or comma separated ({', '.join(SEGMENTERS)})")
    ap.add_argument("--scenarios", type=int, default=0,
                    help="evaluate RandomSuite(N, --seed) instead of a scenario file")
    ap.add_argument("--seed", type=int, default=0, help="RandomSuite seed")
    ap.add_argument("--scenario_text", default="{}",
                    help="YAML overrides for every scenario (with --recordings: the perception "
                         "settings, e.g. a SAM checkpoint)")
    ap.add_argument("--settle", type=float, default=0.0,
                    help="simulated seconds before rendering (e.g. for a FEM leaf to settle)")
    args = ap.parse_args(argv)
    args.backends = [b for x in args.backends for b in x.split(",") if b]
    for b in args.backends:
        if b not in SEGMENTERS:
            ap.error(f"--backends: '{b}' unknown; choose from {', '.join(SEGMENTERS)}")
    if args.scenarios < 0:
        ap.error("--scenarios must be >= 0")
    if args.recordings is not None:
        if args.scenario_file or args.scenario_names is not None or args.scenarios:
            ap.error("--recordings evaluates recorded views; it takes no --scenario_file, "
                     "--scenario_names or --scenarios")
        EvalRecordings(args.out, args.recordings, args.backends, args.scenario_text)
        return 0
    del args.recordings
    EvalSegmentation(**vars(args))
    return 0


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="eval_segmentation.py", strip_debug=True))  # one-line errors; --debug
