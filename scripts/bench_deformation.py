"""Benchmark of the batched ARAP deformation prediction (issue 6).

    .venv/bin/python scripts/bench_deformation.py --out bench.json [--leaf-npz FILE]

Leaf: ``--leaf-npz FILE`` with arrays ``leaf_points_W`` and
``branch_points_W`` (W, m), or by default a synthetic ovate leaf (12 x 6 cm
blade, 1 mm sampling, 2 mm depth-like noise, petiole on a vertical branch),
about 1000 graph nodes at 5 mm voxels. Actions: 15 grasps spread along the
leaf boundary (convex hull of the PCA-projected leaf, 1 cm inward) x 14
directions x 4 distances (2, 4, 6, 8 cm). Times graph building,
factorisation and the ARAP solves (``PrepareAndSolveGrasps``, grasps in
``--workers`` threads; wall clock; ``cpu_seconds`` is the process CPU time
of the same part, useful on a shared machine). The block runs
``--repeats`` times: ``total_seconds`` / ``cpu_seconds`` are the medians of
the runs after the first, i.e. the cost of one planning call in a process
that has planned before (the Diagram's ``DeformationPrediction`` system,
eval workers); ``first_run_seconds`` is the first run, which also pays the
one-time numba start-up of the process (~0.3 s with a warm numba cache,
~20 s right after install while the kernels compile). Dense interpolation
is timed separately (``dense_seconds``) and not part of ``total_seconds``.
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np
from scipy.spatial import ConvexHull

from lmap_drake.deformation.action import MakeActions, PullDirections
from lmap_drake.deformation.graph import BuildLeafGraph
from lmap_drake.deformation.predict import DefaultWorkers, PrepareAndSolveGrasps
from lmap_drake.deformation.synthetic import OvateLeaf
from lmap_drake.deformation.config import DeformationConfig


def BoundaryGrasps(leaf_points_W: np.ndarray, num: int = 15, inset: float = 0.01):
    """``num`` grasp poses (p_WG, R_WG) spread along the convex hull of the
    PCA-projected leaf, ``inset`` m inward. Gripper z (approach) points
    inward in the leaf plane, y (closing) along the leaf normal, so the
    pads' plane (x-z) is the leaf plane."""
    c = leaf_points_W.mean(axis=0)
    _, _, vt = np.linalg.svd(leaf_points_W - c, full_matrices=False)
    uv = (leaf_points_W - c) @ vt[:2].T
    hull = uv[ConvexHull(uv).vertices]
    seg = np.roll(hull, -1, axis=0) - hull
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(seg, axis=1))])
    out = []
    for s in (np.arange(num) + 0.5) * cum[-1] / num:
        k = np.searchsorted(cum, s, side="right") - 1
        q = hull[k] + seg[k] * (s - cum[k]) / np.linalg.norm(seg[k])
        inward = -q / np.linalg.norm(q)
        q2 = q + inset * inward
        p_WG = leaf_points_W[np.argmin(np.linalg.norm(uv - q2, axis=1))]
        z = inward @ vt[:2]
        y = vt[2]
        x = np.cross(y, z)
        out.append((p_WG, np.column_stack([x, y, z])))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True, help="JSON file to write")
    ap.add_argument("--leaf-npz", default=None,
                    help="npz with leaf_points_W and branch_points_W (W, m)")
    ap.add_argument("--factorization", default="inverse", choices=["splu", "cholesky", "inverse"])
    ap.add_argument("--no-dense", action="store_true", help="skip the dense interpolation")
    ap.add_argument("--method", default=None, choices=["lbfgs", "plain"],
                    help="ARAP solver (default: DeformationConfig.arap_method)")
    ap.add_argument("--workers", type=int, default=None,
                    help="threads over grasps (default: the CPUs available)")
    ap.add_argument("--repeats", type=int, default=3,
                    help="timed runs; total_seconds is the median of the runs after the "
                         "first (the first also pays numba's one-time start-up: "
                         "first_run_seconds)")
    ap.add_argument("--relative-tolerance", type=float, default=None,
                    help="override DeformationConfig.relative_tolerance")
    args = ap.parse_args(argv)
    if args.leaf_npz:
        data = np.load(args.leaf_npz)
        leaf, branch = data["leaf_points_W"], data["branch_points_W"]
    else:
        leaf, branch = OvateLeaf(spacing=0.001, noise=0.002, p_WL=[0.5, -0.1, 0.35])
    config = DeformationConfig()
    if args.relative_tolerance is not None:
        config.relative_tolerance = args.relative_tolerance
    if args.method is not None:
        config.arap_method = args.method
    grasps = BoundaryGrasps(leaf, 15, 0.01)
    directions = PullDirections()
    distances = [0.02, 0.04, 0.06, 0.08]

    runs = []
    for _ in range(max(1, args.repeats)):
        t0 = time.perf_counter()
        c0 = time.process_time()
        groups = [MakeActions([(p_WG, R_WG)], directions, distances) for p_WG, R_WG in grasps]
        leaf_graph = BuildLeafGraph(leaf, branch, config)
        solved = PrepareAndSolveGrasps(leaf_graph, groups, config, args.factorization,
                                       args.workers)
        runs.append((time.perf_counter() - t0, time.process_time() - c0))
    warm = runs[1:] or runs
    total = float(np.median([w for w, _ in warm]))
    cpu = float(np.median([c for _, c in warm]))
    iters = np.concatenate([r.iterations for _, r in solved])
    energies = np.concatenate([r.energy for _, r in solved])
    n_nodes = [len(prep.graph.nodes_W) for prep, _ in solved]
    n_edges = [len(prep.graph.edges) for prep, _ in solved]
    dense_seconds = 0.0
    if not args.no_dense:
        td = time.perf_counter()
        for prep, res in solved:
            prep.interpolator.Apply(prep.graph.nodes_W, res.positions_W, res.rotations)
        dense_seconds = time.perf_counter() - td
    result = dict(
        total_seconds=round(total, 4),
        cpu_seconds=round(cpu, 4),
        first_run_seconds=round(runs[0][0], 4),
        run_seconds=[round(w, 4) for w, _ in runs],
        method=config.arap_method,
        relative_tolerance=config.relative_tolerance,
        num_actions=len(iters),
        num_nodes=int(leaf_graph.nodes_W.shape[0]),
        num_edges=int(len(leaf_graph.edges)),
        workers=args.workers or DefaultWorkers(),
        seconds_per_grasp=round(total / len(grasps), 4),
        mean_iterations=round(float(np.mean(iters)), 2),
        max_iterations=int(np.max(iters)),
        num_leaf_nodes=int(leaf_graph.num_leaf),
        num_fixed_nodes=int(leaf_graph.num_fixed),
        mean_grasp_graph_nodes=round(float(np.mean(n_nodes)), 1),
        mean_grasp_graph_edges=round(float(np.mean(n_edges)), 1),
        num_dense_points=int(len(leaf_graph.leaf_points_W)),
        dense_seconds=round(dense_seconds, 4),
        factorization=args.factorization,
        energy_range=[float(np.min(energies)), float(np.max(energies))],
        fraction_converged=round(float(np.mean([r.converged.mean() for _, r in solved])), 3),
    )
    with open(args.out, "w") as f:
        json.dump(result, f, indent=2)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    import sys

    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="bench_deformation.py", strip_debug=True))  # one-line errors; --debug
