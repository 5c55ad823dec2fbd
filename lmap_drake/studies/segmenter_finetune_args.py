"""The flags of ``lmap-drake train-segmenter`` (``segmenter_finetune``),
apart so that the command line starts without importing torch."""
from __future__ import annotations

import argparse
from pathlib import Path


def AddArguments(p: argparse.ArgumentParser) -> None:
    """The flags of ``lmap-drake train-segmenter``."""
    p.add_argument("--recordings", required=True, type=Path,
                   help="folder of run folders (DIR/*/recording/) whose views are annotated")
    p.add_argument("--annotations", type=Path, default=None,
                   help="COCO JSON of polygons (default: LabelMe view<k>_rgb.json beside "
                        "each recorded image)")
    p.add_argument("--out", type=Path, required=True, help="new weights file (.pt)")
    p.add_argument("--init", default="", help="weights to start from (default: the "
                   "scenario's perception.segnet_weights, the shipped ones)")
    p.add_argument("--sim_data", type=Path, default=None,
                   help="folder of simulated samples (scripts/make_segnet_data.py) mixed in")
    p.add_argument("--sim_fraction", type=float, default=0.5,
                   help="share of each batch from --sim_data (default: %(default)s)")
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--batch", type=int, default=8)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--scenario_text", default="{}",
                   help="YAML overrides (the perception depth cut, segnet_weights)")
    p.add_argument("--debug", action="store_true", help="show tracebacks")
