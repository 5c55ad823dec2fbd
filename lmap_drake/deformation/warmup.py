"""Compiles the ARAP kernels (``arap_kernels``, numba ``cache=True``) into
their on-disk cache ahead of the first run, so that the first episode on a
fresh install does not wait ~20-30 s for the compiler. ``make setup`` (and
so the first ``make run`` / ``make test``) runs it after installing:

    python -m lmap_drake.deformation.warmup

It solves a few pulls of a small synthetic leaf through the same code path
as the planner (``ArapProblem.Solve``, the compiled L-BFGS), so the kernels
are compiled for the argument types the pipeline uses. Idempotent: with a
warm cache it takes about a second."""
from __future__ import annotations

import sys
import time

import numpy as np

from lmap_drake.deformation.action import PullDirections
from lmap_drake.deformation.arap import ArapProblem
from lmap_drake.deformation.config import DeformationConfig
from lmap_drake.deformation.graph import BuildGraspGraph, BuildLeafGraph
from lmap_drake.deformation.synthetic import OvateLeaf

# Gripper approaching the leaf tip along -x, closing along the leaf normal.
_R_TIP = np.column_stack([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])


def CompileKernels() -> float:
    """Solves 6 pulls of a synthetic leaf with the compiled solver; returns
    the wall seconds it took (compiling included when the cache was cold)."""
    t0 = time.perf_counter()
    cfg = DeformationConfig()
    leaf, branch = OvateLeaf(spacing=0.003)
    graph = BuildLeafGraph(leaf, branch, cfg)
    p_WG = leaf[np.argmax(leaf[:, 0] - 5 * np.abs(leaf[:, 1]))] - [0.01, 0.0, 0.0]
    g = BuildGraspGraph(graph, p_WG, _R_TIP, cfg)
    dirs = PullDirections()[::7]
    u_c = np.zeros((2 * len(dirs), g.num_constrained, 3))
    u_c[:, g.num_fixed:] = np.array([s * d for d in dirs for s in (0.02, 0.04)])[:, None]
    problem = ArapProblem(g.nodes_W, g.edges, g.weights, g.num_free)
    problem.Solve(u_c, cfg.max_iterations, cfg.relative_tolerance)
    return time.perf_counter() - t0


def main() -> int:
    print("compiling the ARAP kernels (once per install) ...", flush=True)
    print(f"ARAP kernels ready in {CompileKernels():.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
