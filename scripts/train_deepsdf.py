#!/usr/bin/env python
"""Trains the DeepSDF pepper template on the CPU, on procedurally generated
peppers and, optionally, on a folder of scanned pepper meshes.

  nice -n 10 .venv/bin/python scripts/train_deepsdf.py --threads 1      # the shipped template
  .venv/bin/python scripts/train_deepsdf.py --steps 200 --num_shapes 16 --out_dir /tmp/x
  .venv/bin/python scripts/train_deepsdf.py --meshes scans/ --init models/deepsdf/pepper_decoder.pt \\
      --steps 1500 --out_dir models/deepsdf_lab

Writes pepper_decoder.pt, mean_latent.npy and train_summary.json into
--out_dir (default models/deepsdf/). The training is
``lmap_drake.studies.template_training`` (the canonical frame, the scans, the
held-out errors, how the shipped weights were made).
"""
from __future__ import annotations

import sys

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.studies.template_training import DeepSdfTrainingOptions, TrainDeepSdf


def main(argv=None):
    d = DeepSdfTrainingOptions()
    ap = OneLineArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out_dir", default=d.out_dir)
    ap.add_argument("--family", choices=("mixed", "wide", "v1"), default=d.family,
                    help="procedural family: wide (SampleWidePepperShape), v1 (the original "
                         "SamplePepperShape) or mixed (each shape from wide with probability "
                         "--wide_fraction, else v1)")
    ap.add_argument("--wide_fraction", type=float, default=d.wide_fraction)
    ap.add_argument("--num_shapes", type=int, default=d.num_shapes,
                    help="procedural training shapes")
    ap.add_argument("--meshes", default=d.meshes, help="folder of scanned pepper meshes")
    ap.add_argument("--mesh_scale", type=float, default=d.mesh_scale,
                    help="scale of the scan files to metres (0.001 for millimetres)")
    ap.add_argument("--scan_fraction", type=float, default=d.scan_fraction,
                    help="probability mass of the scans when drawing a batch")
    ap.add_argument("--holdout_scans", type=int, default=d.holdout_scans,
                    help="scans kept out of training for the held-out error "
                         "(default: 20 %% of them, at least 1 when there are 2 or more)")
    ap.add_argument("--holdout_family", type=int, default=d.holdout_family,
                    help="unseen procedural shapes for the held-out error")
    ap.add_argument("--holdout_iterations", type=int, default=d.holdout_iterations,
                    help="Adam iterations when fitting a held-out shape's latent")
    ap.add_argument("--init", default=d.init, help="fine-tune from these weights")
    ap.add_argument("--normalize_radius", type=float, default=d.normalize_radius,
                    help="scale every training shape about its centroid to this equal-volume "
                         "radius (m; 0 = keep sizes): the size is then left to SSC's scale and "
                         "the latent codes shape only")
    ap.add_argument("--samples_per_shape", type=int, default=d.samples_per_shape)
    ap.add_argument("--steps", type=int, default=d.steps)
    ap.add_argument("--shapes_per_batch", type=int, default=d.shapes_per_batch)
    ap.add_argument("--points_per_shape", type=int, default=d.points_per_shape)
    ap.add_argument("--width", type=int, default=d.width)
    ap.add_argument("--depth", type=int, default=d.depth)
    ap.add_argument("--latent_size", type=int, default=d.latent_size)
    ap.add_argument("--lr", type=float, default=d.lr)
    ap.add_argument("--code_reg", type=float, default=d.code_reg)
    ap.add_argument("--seed", type=int, default=d.seed)
    ap.add_argument("--threads", type=int, default=d.threads)
    ap.add_argument("--checkpoint_every", type=int, default=d.checkpoint_every)
    ap.add_argument("--time_limit_s", type=float, default=d.time_limit_s,
                    help="stop training early after this many seconds")
    TrainDeepSdf(DeepSdfTrainingOptions(**vars(ap.parse_args(argv))))


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="train_deepsdf.py", strip_debug=True))  # one-line errors; --debug
