#!/usr/bin/env python
"""How hard does the robot load a leaf it only brushes? Pushes of the FEM
leaf by the closed gripper against the planner's bound.

    python scripts/eval_brush.py --out out/brush.json
    python scripts/eval_brush.py --out b.json --points 0.06 0.0 --depths 0.01 0.02

The study is ``lmap_drake.studies.brush`` (the motion, the measures, the
JSON it writes after every push).
"""
from __future__ import annotations

import sys

import numpy as np

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.studies.brush import BrushStudyOptions, RunBrushStudy


def main(argv=None) -> int:
    d = BrushStudyOptions()
    p = OneLineArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True)
    p.add_argument("--points", nargs="+", type=float, default=np.ravel(d.points).tolist(),
                   help="blade points as pairs of leaf coordinates u v (m from the blade's "
                        "base along the midrib, across it)")
    p.add_argument("--depths", nargs="+", type=float, default=d.depths,
                   help="how far (m) the pads' tips go beyond the blade's rest surface")
    p.add_argument("--clearance", type=float, default=d.clearance,
                   help="the blade this far (m) in front of the fruit")
    p.add_argument("--hold", type=float, default=d.hold)
    args = p.parse_args(argv)
    if len(args.points) % 2:
        p.error("--points takes pairs u v")
    args.points = np.reshape(args.points, (-1, 2)).tolist()
    RunBrushStudy(BrushStudyOptions(**vars(args)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
