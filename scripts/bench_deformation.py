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
The benchmark is ``lmap_drake.studies.deformation_benchmark``.
"""
from __future__ import annotations

import json
import sys

from lmap_drake.errors import OneLineArgumentParser
from lmap_drake.studies.deformation_benchmark import BenchDeformation


def main(argv=None):
    ap = OneLineArgumentParser(description=__doc__.split("\n")[0])
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
    result = BenchDeformation(args.leaf_npz, args.factorization, not args.no_dense, args.method,
                              args.workers, args.repeats, args.relative_tolerance)
    with open(args.out, "w") as f:
        json.dump(result, f, indent=2)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    from lmap_drake.errors import RunMain
    sys.exit(RunMain(main, prog="bench_deformation.py", strip_debug=True))  # one-line errors; --debug
