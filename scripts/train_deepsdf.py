#!/usr/bin/env python
"""Trains the DeepSDF pepper template on procedurally generated peppers
(lmap_drake.plants.pepper.SamplePepperShape, canonical frame: metres,
centroid at the origin, peduncle on +z) on the CPU.

Writes into --out_dir (default models/deepsdf/):
  pepper_decoder.pt     decoder weights + config + mean latent + training latents
  mean_latent.npy       the mean latent code (the SSC initialisation)
  train_summary.json    configuration, loss history, timing

The default run (512 shapes, 4000 steps) takes about 5 minutes on 2 idle cores and up to ~25 on a busy machine and reproduces the
committed weights (seeded; bit-identical results need the same torch build
and thread count).

  .venv/bin/python scripts/train_deepsdf.py            # default run
  .venv/bin/python scripts/train_deepsdf.py --steps 200 --num_shapes 16 --out_dir /tmp/x
"""
from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch

from lmap_drake.paths import REPO_ROOT
from lmap_drake.plants.pepper import MakePepper, SamplePepperShape
from lmap_drake.shape import deepsdf


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out_dir", default=str(REPO_ROOT / "models" / "deepsdf"))
    ap.add_argument("--num_shapes", type=int, default=512)
    ap.add_argument("--samples_per_shape", type=int, default=16384)
    ap.add_argument("--steps", type=int, default=4000)
    ap.add_argument("--shapes_per_batch", type=int, default=32)
    ap.add_argument("--points_per_shape", type=int, default=256)
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument("--depth", type=int, default=8)
    ap.add_argument("--latent_size", type=int, default=32)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--code_reg", type=float, default=1e-4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--time_limit_s", type=float, default=25 * 60,
                    help="stop training early after this many seconds")
    a = ap.parse_args(argv)
    torch.set_num_threads(a.threads)
    t_start = time.time()
    out = Path(a.out_dir)
    out.mkdir(parents=True, exist_ok=True)

    rng = np.random.default_rng(a.seed)
    shapes, pts, sdf = [], [], []
    from tqdm import tqdm
    for i in tqdm(range(a.num_shapes), desc="sampling shapes", unit="shape", file=sys.stderr):
        shape = SamplePepperShape(rng)
        pep = MakePepper(shape, subdivisions=4)
        p, d = deepsdf.MeshSdfSamples(pep.mesh.vertices, pep.mesh.faces,
                                      a.samples_per_shape, rng)
        shapes.append(shape)
        pts.append(p)
        sdf.append(d)
    pts, sdf = np.stack(pts), np.stack(sdf)
    t_data = time.time() - t_start

    dec, latents, hist = deepsdf.TrainDecoder(
        pts, sdf, latent_size=a.latent_size, width=a.width, depth=a.depth, steps=a.steps,
        shapes_per_batch=a.shapes_per_batch, points_per_shape=a.points_per_shape, lr=a.lr,
        lr_latent=a.lr, code_reg=a.code_reg, seed=a.seed,
        log=lambda s: print(s, flush=True), time_limit_s=a.time_limit_s)
    mean = latents.mean(0)
    shape_params = [dict(size=list(s.size), lobes=s.lobes, lobe_depth=s.lobe_depth,
                         variant=s.variant, squareness=s.squareness, shoulder=s.shoulder,
                         taper=s.taper, cone=s.cone, lobe_phase=s.lobe_phase,
                         asymmetry=s.asymmetry, asymmetry_phase=s.asymmetry_phase)
                    for s in shapes]
    wpath = out / "pepper_decoder.pt"
    deepsdf.SaveDecoder(wpath, dec, mean, extra={
        "train_latents": torch.as_tensor(latents, dtype=torch.float32),
        "train_seed": a.seed})
    np.save(out / "mean_latent.npy", mean.astype(np.float32))
    t_total = time.time() - t_start
    summary = dict(
        args=vars(a), decoder=dec.config(), clamp_m=deepsdf.CLAMP,
        cube_radius_m=deepsdf.CUBE_RADIUS, data_seconds=round(t_data, 1),
        total_seconds=round(t_total, 1), weights_bytes=wpath.stat().st_size,
        final_l1_mm=hist[-1]["l1_mm"] if hist else None,
        mean_latent_norm=float(np.linalg.norm(mean)),
        latent_norm_mean=float(np.linalg.norm(latents, axis=1).mean()),
        torch=torch.__version__, machine=platform.machine(), history=hist,
        shapes=shape_params)
    (out / "train_summary.json").write_text(json.dumps(summary, indent=1))
    print(f"done: {len(shapes)} shapes, {hist[-1]['step'] if hist else 0} steps, "
          f"final L1 {summary['final_l1_mm']:.3f} mm, weights {wpath} "
          f"({summary['weights_bytes'] / 1e6:.2f} MB), total {t_total / 60:.1f} min")


if __name__ == "__main__":
    import sys

    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="train_deepsdf.py", strip_debug=True))  # one-line errors; --debug
