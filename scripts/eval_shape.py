#!/usr/bin/env python
"""The analogue of paper Table I: shape completion with initial occlusion
and without occlusion (leaf removed) for SupEps, HoMa-style and SSC.

  .venv/bin/python scripts/eval_shape.py --out out/eval_shape.json
  .venv/bin/python scripts/make_test_peppers.py --out out/test_peppers --count 6
  .venv/bin/python scripts/eval_shape.py --fruit_mesh_dir out/test_peppers --out out/shape_files.json

Writes FILE.json, FILE.md (table) and FILE_figures/. The study is
``lmap_drake.studies.shape_table`` (the cases, the metrics, the JSON
layout). A mesh that fails the checks stops the run before anything is
evaluated (exit code 2, the file named).
"""
from __future__ import annotations

import sys

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.studies.shape_table import CONDITIONS, RunShapeTable, ShapeTableOptions


def main(argv=None):
    d = ShapeTableOptions()
    ap = OneLineArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--md", default=d.md, help="Markdown file (default: --out with .md)")
    ap.add_argument("--methods", default=d.methods)
    ap.add_argument("--num_cases", type=int, default=d.num_cases)
    ap.add_argument("--source", choices=("auto", "synthetic", "suite"), default=d.source)
    ap.add_argument("--threads", type=int, default=d.threads,
                    help="torch threads (1 avoids oversubscription on a shared 2-core machine)")
    ap.add_argument("--iterations", type=int, default=d.iterations)
    ap.add_argument("--seeds", default=d.seeds, help="optimiser seeds, comma-separated")
    ap.add_argument("--shape_text", default=d.shape_text,
                    help="YAML overrides of ShapeConfig, e.g. \"{ssc: {peduncle_max_distance: 0.03}}\"")
    ap.add_argument("--fruit_mesh_dir", default=d.fruit_mesh_dir,
                    help="evaluate the pepper meshes DIR/NAME.{obj,ply,stl} (+ NAME.peduncle.*) "
                         "in the suite's scenes instead of the procedural peppers")
    ap.add_argument("--conditions", default=d.conditions,
                    help=f"comma-separated: {', '.join(CONDITIONS)}")
    ap.add_argument("--scenario_names", default=d.scenario_names,
                    help="comma-separated suite scenes (default: the first --num_cases)")
    ap.add_argument("--figures", type=int, default=d.figures,
                    help="pictures of the first N cases of each fruit (of the run without "
                         "--fruit_mesh_dir), each condition: the camera's and a side view of "
                         "the truth and every method's estimate, in OUT_figures/ (0: none)")
    RunShapeTable(ShapeTableOptions(**vars(ap.parse_args(argv))))


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="eval_shape.py", strip_debug=True))  # one-line errors; --debug
