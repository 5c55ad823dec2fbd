"""Benchmark of the batched ARAP deformation prediction (issue 6), behind
``scripts/bench_deformation.py`` (its help says what is timed and what the
JSON holds).
"""
from __future__ import annotations

import time

import numpy as np
from scipy.spatial import ConvexHull

from lmap_drake.deformation.action import MakeActions, PullDirections
from lmap_drake.deformation.config import DeformationConfig
from lmap_drake.deformation.graph import BuildLeafGraph
from lmap_drake.deformation.predict import DefaultWorkers, PrepareAndSolveGrasps
from lmap_drake.deformation.synthetic import OvateLeaf


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


def BenchDeformation(leaf_npz: str | None = None, factorization: str = "inverse",
                     dense: bool = True, method: str | None = None,
                     workers: int | None = None, repeats: int = 3,
                     relative_tolerance: float | None = None) -> dict:
    """Times graph building, factorisation and the ARAP solves of 15 boundary
    grasps x 14 directions x 4 distances on the leaf of ``leaf_npz`` (arrays
    ``leaf_points_W``, ``branch_points_W``; W, m) or the synthetic ovate
    leaf; ``repeats`` runs (the first also pays numba's start-up), then the
    dense interpolation unless ``dense`` is False. The result JSON's fields."""
    if leaf_npz:
        data = np.load(leaf_npz, allow_pickle=False)
        leaf, branch = data["leaf_points_W"], data["branch_points_W"]
    else:
        leaf, branch = OvateLeaf(spacing=0.001, noise=0.002, p_WL=[0.5, -0.1, 0.35])
    config = DeformationConfig()
    if relative_tolerance is not None:
        config.relative_tolerance = relative_tolerance
    if method is not None:
        config.arap_method = method
    grasps = BoundaryGrasps(leaf, 15, 0.01)
    directions = PullDirections()
    distances = [0.02, 0.04, 0.06, 0.08]

    runs = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        c0 = time.process_time()
        groups = [MakeActions([(p_WG, R_WG)], directions, distances) for p_WG, R_WG in grasps]
        leaf_graph = BuildLeafGraph(leaf, branch, config)
        solved = PrepareAndSolveGrasps(leaf_graph, groups, config, factorization,
                                       workers)
        runs.append((time.perf_counter() - t0, time.process_time() - c0))
    warm = runs[1:] or runs
    total = float(np.median([w for w, _ in warm]))
    cpu = float(np.median([c for _, c in warm]))
    iters = np.concatenate([r.iterations for _, r in solved])
    energies = np.concatenate([r.energy for _, r in solved])
    n_nodes = [len(prep.graph.nodes_W) for prep, _ in solved]
    n_edges = [len(prep.graph.edges) for prep, _ in solved]
    dense_seconds = 0.0
    if dense:
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
        workers=workers or DefaultWorkers(),
        seconds_per_grasp=round(total / len(grasps), 4),
        mean_iterations=round(float(np.mean(iters)), 2),
        max_iterations=int(np.max(iters)),
        num_leaf_nodes=int(leaf_graph.num_leaf),
        num_fixed_nodes=int(leaf_graph.num_fixed),
        mean_grasp_graph_nodes=round(float(np.mean(n_nodes)), 1),
        mean_grasp_graph_edges=round(float(np.mean(n_edges)), 1),
        num_dense_points=int(len(leaf_graph.leaf_points_W)),
        dense_seconds=round(dense_seconds, 4),
        factorization=factorization,
        energy_range=[float(np.min(energies)), float(np.max(energies))],
        fraction_converged=round(float(np.mean([r.converged.mean() for _, r in solved])), 3),
    )
    return result
