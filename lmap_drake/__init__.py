"""lmap_drake: safe leaf manipulation (LMAP) and scene-consistent shape
completion (SSC) for occluded fruits, as a Drake systems-diagram application."""

import os as _os

# Many small dense products (ARAP, IK, SDF batches): multi-threaded OpenBLAS
# is much slower for them on a shared 2-core machine (measured: a 594 x 594
# inverse 4 s instead of 0.04 s). Users can override it in the environment.
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

__version__ = "0.1.0"
