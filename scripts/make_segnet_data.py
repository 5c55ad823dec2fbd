#!/usr/bin/env python
"""Randomised simulator renders for training the segmentation network
(``lmap_drake/perception/segnet.py``): domain randomisation of the plant,
of every colour, of the lights, of the camera pose and model and of the arm
pose; with ``--held_leaf F`` a fraction F of the scenes shows a leaf held
and turned by the gripper as the planner's actions leave it; with
``--greenhouse F`` a fraction F is a random greenhouse scene.

    python scripts/make_segnet_data.py --out out/segnet_data --count 400 --seed 10000

Sample ``i`` depends only on ``seed + i`` (a run can be extended or resumed;
existing files are kept). The renders are ``lmap_drake.studies.segnet_data``
(what is randomised, what each ``NNNNN.npz`` holds).
"""
from __future__ import annotations

import sys

from lmap_drake.errors import InputError, OneLineArgumentParser
from lmap_drake.studies.segnet_data import MakeSegNetData


def main(argv=None) -> int:
    ap = OneLineArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--count", type=int, default=400)
    ap.add_argument("--seed", type=int, default=10000, help="first sample seed")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--arm_near_leaf", type=float, default=0.5,
                    help="fraction of scenes with the gripper at the leaf (the view after a "
                         "grasp); the rest keep the arm near its initial pose")
    ap.add_argument("--multi", type=float, default=0.0,
                    help="fraction of scenes with a multi-fruit plant (2-4 fruits on side "
                         "shoots with their stalks, 2-6 leaves)")
    ap.add_argument("--held_leaf", type=float, default=0.0,
                    help="fraction of scenes with a leaf held by the gripper, turned about its "
                         "attachment as the planner's twists, arcs and pulls leave it")
    ap.add_argument("--greenhouse", type=float, default=0.0,
                    help="fraction of scenes from the greenhouse world (random textured "
                         "plants of 1-2 stems and 15-45 leaves, dressing, neighbouring row, "
                         "greenhouse or random lights, exposure and white balance)")
    args = ap.parse_args(argv)
    try:
        MakeSegNetData(**vars(args))
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="make_segnet_data.py", strip_debug=True))  # one-line errors; --debug
