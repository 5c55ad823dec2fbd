#!/usr/bin/env python
"""Trains the RGB-D segmentation network (``lmap_drake/perception/segnet.py``)
on the randomised renders of ``scripts/make_segnet_data.py``.

    python scripts/make_segnet_data.py --out out/segnet_data --count 520 --seed 10000
    python scripts/train_segnet.py --data out/segnet_data --out models/segnet/segnet.pt

The training is ``lmap_drake.perception.training`` (crops, loss, the
held-out IoU in the weights' ``meta`` and ``OUT.json``).
"""
from __future__ import annotations

import sys

from lmap_drake.errors import InputError, OneLineArgumentParser
from lmap_drake.perception.training import SegNetTrainingOptions, TrainSegNet


def main(argv=None) -> int:
    d = SegNetTrainingOptions()
    ap = OneLineArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", required=True, help="folder of make_segnet_data.py samples")
    ap.add_argument("--out", default=d.out)
    ap.add_argument("--steps", type=int, default=d.steps)
    ap.add_argument("--batch", type=int, default=d.batch)
    ap.add_argument("--lr", type=float, default=d.lr)
    ap.add_argument("--threads", type=int, default=d.threads)
    ap.add_argument("--seed", type=int, default=d.seed)
    ap.add_argument("--init", default=d.init, help="start from these weights (fine-tuning)")
    ap.add_argument("--no_boundary_head", dest="boundary_head", action="store_false",
                    help="do not learn the leaf boundary channel (perception.leaf_boundaries)")
    args = ap.parse_args(argv)
    try:
        TrainSegNet(SegNetTrainingOptions(**vars(args)))
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="train_segnet.py", strip_debug=True))  # one-line errors; --debug
