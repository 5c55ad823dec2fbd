"""Compiled (numba) kernels of the L-BFGS ARAP solver
(``ArapProblem.SolveAccelerated``; the maths is in ``arap.py``):
``polar`` (per-node rotations), ``energy`` (E(x) and its gradient),
``lbfgs`` (the driver, ``SolveTasks``), ``jit`` (the numba flags).

Actions are solved in ``nl`` lanes (``LANES``): per node, every array holds
its components times the lanes, lane last, so that each node or edge
operation is one vector loop over (component, lane). A lane takes the
next ready action as soon as its previous one stops (an action is ready
once the action it is warm-started from is solved), so the lanes stay busy
although actions need different iteration counts. Per action the iterates
are those of the batched numpy formulation, except that the per-node polar
rotations are warm-started from the predecessor action and the Newton
update uses the Cayley map (same fixed point, see ``polar.PolarLanes``).

Layouts, per node: vectors (3 nl) [k * nl + l]; quaternions (4 nl)
[c * nl + l]; 3 x 3 matrices (9 nl), column-major [(3 b + k) * nl + l] =
M[k, b]. The lane count is a run-time argument on purpose: numba leaves
SLP vectorisation off, and a constant trip count would be unrolled into
scalar code before the loop vectoriser runs.

Compiled with ``cache=True``: the first call after installing or editing
these files compiles for about 20 s and stores the machine code under
``__pycache__``; in later processes importing this package costs ~0.3 s
(numba) and the first call ~0.3 s (numba's one-time initialisation and
loading the cached code). Kernels release the GIL (grasps in threads).
numba checks a cached kernel against its own file only (numba issue
#1833), while ``SolveTasks`` inlines the kernels of the sibling modules:
``_DropStaleCache`` clears this package's cache when any of its sources
changed.
"""
from __future__ import annotations

import hashlib
from pathlib import Path


def _DropStaleCache() -> None:
    """Deletes the numba cache files of this package when the hash of its
    sources differs from the one stored beside them (best effort: a
    read-only install keeps its cache)."""
    here = Path(__file__).parent
    digest = hashlib.sha256(b"".join(p.read_bytes() for p in sorted(here.glob("*.py")))
                            ).hexdigest()
    stamp = here / "__pycache__" / "arap_kernels.sources.sha256"
    try:
        if stamp.read_text() == digest:
            return
    except OSError:
        pass
    try:
        for f in stamp.parent.glob("*.nb[ic]"):
            f.unlink(missing_ok=True)
        stamp.parent.mkdir(exist_ok=True)
        stamp.write_text(digest)
    except OSError:
        pass


_DropStaleCache()

from lmap_drake.deformation.arap_kernels.jit import LANES  # noqa: E402
from lmap_drake.deformation.arap_kernels.lbfgs import SolveTasks  # noqa: E402
from lmap_drake.deformation.arap_kernels.polar import PolarRotations  # noqa: E402

__all__ = ["LANES", "PolarRotations", "SolveTasks"]
