#!/usr/bin/env python
"""How well the segmentation network sees a leaf while the gripper holds it,
on the recorded views of simulated episodes (``lmap-drake run`` writes
them to ``OUT/recording/``, with the renderer's labels).

    python scripts/eval_held_leaf.py --runs out/run1 out/run2 ... --out held.json
    python scripts/eval_held_leaf.py --runs out/*/ --weights old.pt models/segnet/segnet.pt \\
        --out held.json

The study is ``lmap_drake.studies.held_leaf`` (what a held view is, the
JSON it writes).
"""
from __future__ import annotations

import sys
from pathlib import Path

from lmap_drake.errors import InputError, OneLineArgumentParser
from lmap_drake.studies.held_leaf import EvalHeldLeaf


def main(argv=None) -> int:
    ap = OneLineArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", nargs="+", required=True, type=Path,
                    help="episode output folders (each with scenario.yaml and recording/)")
    ap.add_argument("--weights", nargs="+", default=None,
                    help="segnet weights files (default: the shipped one)")
    ap.add_argument("--out", required=True, type=Path, help="output JSON file")
    a = ap.parse_args(argv)
    try:
        EvalHeldLeaf(a.runs, a.weights, a.out)
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="eval_held_leaf.py", strip_debug=True))
