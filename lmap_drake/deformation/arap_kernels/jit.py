"""How every ARAP kernel is compiled (numba flags), and the lane count."""
from __future__ import annotations

LANES = 8
# fastmath without "nnan"/"ninf": the solver compares against inf.
OPTS = dict(cache=True, nogil=True, error_model="numpy",
            fastmath={"nsz", "arcp", "contract", "afn", "reassoc"})
# Leaf kernels neither allocate nor keep references: no reference counting
# (its atomic increments cost as much as the small kernels themselves).
LEAF = dict(OPTS, _nrt=False)
