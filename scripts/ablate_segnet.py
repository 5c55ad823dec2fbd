#!/usr/bin/env python
"""What each randomisation of the greenhouse training renders buys: one
fine-tune per randomisation group switched off, scored on held-out random
greenhouse plants (``lmap_drake.studies.segnet_ablation``).

    python scripts/ablate_segnet.py --out out/segnet_ablation

Writes ``OUT/ablation.json``, ``OUT/ablation.md`` and ``OUT/ablation.png``;
renders, weights and evaluations stay in ``OUT/work/`` (a rerun resumes).
"""
from __future__ import annotations

import sys

from lmap_drake.errors import InputError, OneLineArgumentParser
from lmap_drake.studies.segnet_ablation import VARIANTS, AblationOptions, RunAblation


def main(argv=None) -> int:
    d = AblationOptions()
    ap = OneLineArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=d.out, help="output folder")
    ap.add_argument("--variants", default=",".join(d.variants),
                    help=f"comma-separated, from {', '.join(VARIANTS)}")
    ap.add_argument("--count", type=int, default=d.count, help="training renders per variant")
    ap.add_argument("--seed", type=int, default=d.seed, help="first training render seed")
    ap.add_argument("--steps", type=int, default=d.steps, help="fine-tuning steps per variant")
    ap.add_argument("--lr", type=float, default=d.lr)
    ap.add_argument("--init", default=d.init, help="start weights of every variant")
    ap.add_argument("--heldout", type=int, default=d.heldout, help="held-out plants scored")
    ap.add_argument("--heldout_seed", type=int, default=d.heldout_seed)
    ap.add_argument("--workers", type=int, default=d.workers, help="render processes")
    ap.add_argument("--threads", type=int, default=d.threads, help="torch threads in training")
    a = ap.parse_args(argv)
    try:
        RunAblation(AblationOptions(**{**vars(a), "variants": tuple(
            v.strip() for v in a.variants.split(",") if v.strip())}))
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="ablate_segnet.py", strip_debug=True))  # one-line errors; --debug
