"""The install-time warm-up leaves the compiled ARAP kernels in numba's
on-disk cache, so the first episode does not compile them."""
from pathlib import Path

import lmap_drake.deformation.arap_kernels as K
from lmap_drake.deformation.warmup import CompileKernels


def test_warmup_fills_the_kernel_cache():
    assert CompileKernels() > 0
    cache = Path(K.__file__).parent / "__pycache__"
    indexes = {p.name.split("-")[0] for p in cache.glob("*.nbi")}
    assert {"lbfgs.SolveTasks", "polar.PolarRotations"} <= indexes, sorted(indexes)
    assert list(cache.glob("lbfgs.SolveTasks-*.nbc"))   # the machine code itself
