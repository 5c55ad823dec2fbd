#!/usr/bin/env python
"""Leaf instances against the true leaves on rendered greenhouse views.

    python scripts/make_suite.py --greenhouse --random 3 --seed 57 --out out/gh57.yaml
    python scripts/eval_leaf_instances.py --render out/leafviews \
        --scenario_file diagrams/greenhouse_suite.yaml out/gh57.yaml
    python scripts/eval_leaf_instances.py --views out/leafviews --out out/leaf_instances.json

The study is ``lmap_drake.studies.leaf_instances`` (what each figure means:
docs/explanation/leaf-instances.md).
"""
from __future__ import annotations

import sys
from pathlib import Path

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.studies.leaf_instances import CLASS_MAPS, EvalLeafInstances, RenderViews


def main(argv=None) -> int:
    ap = OneLineArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--render", type=Path, default=None,
                    help="render camera0's view of every scenario of --scenario_file into "
                         "this folder (<name>.npz; views already there are kept)")
    ap.add_argument("--scenario_file", type=Path, nargs="+", default=[],
                    help="scenario YAML files to render (with --render)")
    ap.add_argument("--views", type=Path, nargs="+", default=[],
                    help="view files (.npz from --render) or folders of them to evaluate")
    ap.add_argument("--out", default=None, help="output JSON (with --views)")
    ap.add_argument("--class_maps", nargs="+", default=list(CLASS_MAPS),
                    help=f"class maps to score the instances of ({', '.join(CLASS_MAPS)})")
    ap.add_argument("--min_pixels", type=int, default=200,
                    help="smallest visible true leaf counted (pixels)")
    ap.add_argument("--scenario_text", default="",
                    help="YAML overrides of the default scenario's perception, e.g. "
                         "'{perception: {segnet_weights: models/segnet/segnet_greenhouse.pt}}'")
    ap.add_argument("--baseline", action="store_true",
                    help="the instance steps as before issue 57 (no neck cuts; leaf sizes "
                         "split without checking their spread), for a before/after")
    args = ap.parse_args(argv)
    for c in args.class_maps:
        if c not in CLASS_MAPS:
            ap.error(f"--class_maps: '{c}' unknown; choose from {', '.join(CLASS_MAPS)}")
    if args.min_pixels < 1:
        ap.error(f"--min_pixels must be >= 1, got {args.min_pixels}")
    if args.render is None and not args.views:
        ap.error("give --render DIR --scenario_file F... or --views V... --out OUT")
    if args.render is not None:
        if not args.scenario_file:
            ap.error("--render needs --scenario_file")
        for f in args.scenario_file:
            if not f.is_file():
                ap.error(f"--scenario_file {f}: no such file")
        RenderViews(args.render, args.scenario_file)
    if args.views:
        if not args.out:
            ap.error("--views needs --out")
        files = []
        for v in args.views:
            if v.is_dir():
                files += sorted(p for p in v.glob("*.npz") if not p.name.endswith(".partial.npz"))
            elif v.is_file():
                files.append(v)
            else:
                ap.error(f"--views {v}: no such file or folder")
        if not files:
            ap.error(f"--views {' '.join(map(str, args.views))}: no .npz view in it")
        EvalLeafInstances(args.out, files, args.class_maps, args.min_pixels, args.baseline,
                          scenario_text=args.scenario_text)
    return 0


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="eval_leaf_instances.py", strip_debug=True))  # one-line errors
