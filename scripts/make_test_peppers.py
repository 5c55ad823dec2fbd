#!/usr/bin/env python
"""Pepper-like test meshes made by other means than the procedural family
(``lmap_drake/plants/pepper.py``), for ``scripts/eval_shape.py
--fruit_mesh_dir`` and ``plant_scene.fruit.mesh_file``: kinds ``blob``,
``bent``, ``sculpted`` and (not by default) ``scan``, each with a curved
tube peduncle unless ``--no_peduncle``; see
``lmap_drake.plants.pepper_meshes``.

  .venv/bin/python scripts/make_test_peppers.py --out out/test_peppers --count 6 --seed 0
"""
from __future__ import annotations

import sys

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.plants.pepper_meshes import KINDS, WriteTestPeppers


def main(argv=None):
    ap = OneLineArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--count", type=int, default=6)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--no_peduncle", action="store_true")
    a = ap.parse_args(argv)
    WriteTestPeppers(a.out, a.count, a.seed, a.kinds.split(","), not a.no_peduncle)
    return 0


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="make_test_peppers.py", strip_debug=True))
