#!/usr/bin/env python
"""The analogue of paper Table I: shape completion with initial occlusion
and without occlusion (leaf removed) for SupEps, HoMa-style and SSC.

Cases come from the 12-scenario plant suite when ``diagrams/suite.yaml``
exists (``--source auto``, the default, or ``--source suite``), otherwise
from the synthetic benchmark of ``lmap_drake.shape.benchmark`` (12 seeded
peppers of the project's family beside a branch, a leaf-like plate hiding
35-75 % of the fruit, exact labels). The JSON and the Markdown say which.

  .venv/bin/python scripts/eval_shape.py --out out/eval_shape.json

Writes FILE.json ({"source", "ssc": {"initial_occlusion": {"chamfer_cm",
"volume_err_cm3", "center_err_cm", "angle_err_deg", "seconds"},
"without_occlusion": {...}}, ..., "rows": [...]}) and FILE.md (table).
``seconds`` is the fruit-completion time per fruit (free space + fit;
branch completion reported separately as ``branch_seconds``).

``--seeds 0,1,2,3`` repeats every fit with those optimiser seeds (surface /
negative subsampling): the tables are then means over cases and seeds, and
``"seed_std"`` holds, per method and condition, the standard deviation over
seeds of the per-seed means (the run-to-run noise a difference between two
methods has to exceed). Rows of the DeepSDF methods also record how many
iterations had an active negative loss (``neg_iters``) and an active
peduncle loss (``ped_iters``), and how many negative points the estimate
still has inside it (``neg_inside``: leaf, observed branch, free space,
more than 0.5 mm deep).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from pydrake.common.yaml import yaml_load_typed

from lmap_drake.paths import REPO_ROOT
from lmap_drake.scenario import ShapeConfig
from lmap_drake.shape import benchmark
from lmap_drake.shape.completion import CompleteScene
from lmap_drake.shape.deepsdf import LoadDecoder
from lmap_drake.shape.free_space import FreeSpacePoints
from lmap_drake.shape.metrics import ShapeMetrics
from lmap_drake.shape.ssc import SscParams

METRICS = ("chamfer_cm", "volume_err_cm3", "center_err_cm", "angle_err_deg", "seconds")
CONDITIONS = ("initial_occlusion", "without_occlusion")
NAMES = {"supeps": "SupEps", "homa": "HoMa (DeepSDF, no scene)", "ssc": "SSC"}


def Cases(source: str, num: int):
    suite = REPO_ROOT / benchmark.SUITE_FILE
    if source == "suite" or (source == "auto" and suite.is_file()):
        names = benchmark.SuiteScenarioNames(suite)[:num]
        for n in names:
            yield "suite", n, lambda occ, n=n: benchmark.MakeSuiteCase(suite, n, occ)
    else:
        for i in range(num):
            yield "synthetic", f"synthetic_{i:02d}", \
                lambda occ, i=i: benchmark.MakeSyntheticCase(i, occ)


def SceneNegatives(sem, voxel: float) -> np.ndarray:
    """The observed negatives of SSC (leaf, branch, free space; W, m)."""
    cam = np.asarray(sem.X_WC, float)[:3, 3]
    obs = [p for p in (sem.fruit_points_W, sem.leaf_points_W, sem.branch_points_W,
                       sem.background_points_W) if len(p)]
    free = FreeSpacePoints(cam, np.vstack(obs), sem.fruit_points_W, voxel)
    return np.vstack([np.asarray(p, float).reshape(-1, 3) for p in
                      (sem.leaf_points_W, sem.branch_points_W, free)])


def Markdown(res: dict, methods) -> str:
    seeds = res.get("seeds", [0])
    lines = [f"Shape completion, {res['num_cases']} cases, source: {res['source']} "
             f"(mean over cases" + (f" and seeds {seeds}" if len(seeds) > 1 else "") +
             f"; seconds = fruit completion per fruit, {res['threads']} torch threads)", "",
             "| condition | method | Chamfer (cm) | volume err (cm^3) | centre err (cm) "
             "| angle err (deg) | s/fruit |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for cond in CONDITIONS:
        for m in methods:
            r = res[m][cond]
            lines.append(f"| {cond.replace('_', ' ')} | {NAMES[m]} | {r['chamfer_cm']:.2f} | "
                         f"{r['volume_err_cm3']:.1f} | {r['center_err_cm']:.2f} | "
                         f"{r['angle_err_deg']:.1f} | {r['seconds']:.2f} |")
    if "seed_std" in res:
        lines += ["", "Standard deviation over seeds of the mean (Chamfer / volume / centre / "
                  "angle):", ""]
        for cond in CONDITIONS:
            for m in methods:
                r = res["seed_std"][m][cond]
                lines.append(f"- {cond.replace('_', ' ')}, {NAMES[m]}: {r['chamfer_cm']:.3f} / "
                             f"{r['volume_err_cm3']:.2f} / {r['center_err_cm']:.3f} / "
                             f"{r['angle_err_deg']:.2f}")
    lines += ["", "TCoRe is not evaluated: its trained weights are not available."]
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--md", default=None, help="Markdown file (default: --out with .md)")
    ap.add_argument("--methods", default="supeps,homa,ssc")
    ap.add_argument("--num_cases", type=int, default=12)
    ap.add_argument("--source", choices=("auto", "synthetic", "suite"), default="auto")
    ap.add_argument("--threads", type=int, default=1,
                    help="torch threads (1 avoids oversubscription on a shared 2-core machine)")
    ap.add_argument("--iterations", type=int, default=None)
    ap.add_argument("--seeds", default="0", help="optimiser seeds, comma-separated")
    ap.add_argument("--shape_text", default="{}",
                    help="YAML overrides of ShapeConfig, e.g. \"{peduncle_max_distance: 0.03}\"")
    a = ap.parse_args(argv)
    torch.set_num_threads(a.threads)
    methods = a.methods.split(",")
    cfg = yaml_load_typed(schema=ShapeConfig, data=a.shape_text, defaults=ShapeConfig())
    dec, mean, _ = LoadDecoder(cfg.weights_file, getattr(cfg, "mean_latent_file", "") or None)
    P = SscParams.FromConfig(cfg)
    if a.iterations:
        P.iterations = a.iterations
    seeds = [int(x) for x in a.seeds.split(",")]
    rows, source = [], None
    t_all = time.time()
    for src, name, make in Cases(a.source, a.num_cases):
        source = src
        for cond in CONDITIONS:
            case = make(cond == "initial_occlusion")
            sem = case.semantic
            negatives = None
            for seed in seeds:
                P.seed = seed
                for m in methods:
                    tm = {}
                    est = CompleteScene(sem, dec, mean, P, m, cfg.free_space_voxel, timings=tm)
                    f = est.fruit
                    r = ShapeMetrics(f.vertices_W, f.faces, f.peduncle_axis_W,
                                     case.gt_vertices_W, case.gt_faces, case.gt_axis_W)
                    r.update(seconds=tm.get("fruit_s", 0.0),
                             branch_seconds=tm.get("branch_s", 0.0), case=case.name,
                             condition=cond, method=m, seed=seed,
                             visible_fraction=case.visible_fraction,
                             num_fruit_points=int(len(sem.fruit_points_W)))
                    if m != "supeps":
                        if negatives is None:
                            negatives = SceneNegatives(sem, cfg.free_space_voxel)
                        tr = [t for t in f.loss_trace if t.get("it", -1) >= 0]
                        r.update(neg_iters=int(sum(t["neg"] > 0 for t in tr)),
                                 ped_iters=int(sum(t["ped"] > 0 for t in tr)),
                                 neg_inside=int((f.sdf_W(negatives) < -5e-4).sum()))
                    rows.append(r)
                    print(f"{case.name:28s} {cond:18s} {m:7s} s{seed} CD {r['chamfer_cm']:.2f} cm"
                          f"  V {r['volume_err_cm3']:6.1f} cm3  c {r['center_err_cm']:.2f} cm  "
                          f"ang {r['angle_err_deg']:5.1f} deg  {r['seconds']:.2f} s  "
                          f"(vis {case.visible_fraction:.2f})", flush=True)
    res = {"source": source, "num_cases": len({r["case"] for r in rows}), "threads": a.threads,
           "iterations": P.iterations, "seeds": seeds,
           "total_seconds": round(time.time() - t_all, 1)}
    for m in methods:
        res[m] = {}
        for cond in CONDITIONS:
            sel = [r for r in rows if r["method"] == m and r["condition"] == cond]
            res[m][cond] = {k: float(np.mean([r[k] for r in sel])) for k in METRICS}
    if len(seeds) > 1:
        res["seed_std"] = {m: {cond: {k: float(np.std([np.mean(
            [r[k] for r in rows if r["method"] == m and r["condition"] == cond
             and r["seed"] == sd]) for sd in seeds])) for k in METRICS} for cond in CONDITIONS}
            for m in methods}
    res["rows"] = rows
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(res, indent=1))
    md = Markdown(res, methods)
    Path(a.md or out.with_suffix(".md")).write_text(md)
    print(md)


if __name__ == "__main__":
    import sys

    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="eval_shape.py", strip_debug=True))  # one-line errors; --debug
