#!/usr/bin/env python3
"""Writes scenario files for plant suites.

    python scripts/make_suite.py                      # diagrams/suite.yaml (the 12 paper-like scenes)
    python scripts/make_suite.py --random 50 --seed 3 --out out/random_50.yaml
    python scripts/make_suite.py --multi              # diagrams/multi_suite.yaml (multi-fruit plants)
    python scripts/make_suite.py --multi --random 6 --seed 7   # random multi-fruit plants
    python scripts/make_suite.py --greenhouse         # diagrams/greenhouse_suite.yaml
    python scripts/make_suite.py --greenhouse --random 6 --seed 7   # random greenhouse plants
    python scripts/make_suite.py --multi --random 6 --seed 7 --fruit_mesh_dir DIR
        # their peppers drawn from DIR/NAME.{obj,ply,stl} (+ NAME.peduncle.*)
"""
import argparse
import sys

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.plants.suite import WriteSuiteFile


def main(argv=None) -> None:
    p = OneLineArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--random", type=int, default=0, help="number of random scenes")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None)
    p.add_argument("--multi", action="store_true", help="the multi-fruit plant scenes")
    p.add_argument("--greenhouse", action="store_true",
                   help="the greenhouse plant scenes (plant_scene.kind: greenhouse)")
    p.add_argument("--fruit_mesh_dir", default=None,
                   help="with --random: every pepper drawn from the meshes DIR/NAME.{obj,ply,stl} "
                        "(+ NAME.peduncle.*) instead of the procedural family")
    a = p.parse_args(argv)
    if a.seed < 0 or a.random < 0:
        p.error(f"--seed and --random must be >= 0, got --seed {a.seed} --random {a.random}")
    if a.greenhouse and (a.multi or a.fruit_mesh_dir):
        p.error("--greenhouse takes neither --multi nor --fruit_mesh_dir")
    if a.fruit_mesh_dir and a.random <= 0:
        p.error("--fruit_mesh_dir needs --random N")
    n, out = WriteSuiteFile(a.out, a.random, a.seed, a.multi, a.fruit_mesh_dir, a.greenhouse)
    print(f"wrote {n} scenarios to {out}")


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="make_suite.py", strip_debug=True))  # one-line errors; --debug
