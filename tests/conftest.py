import os

import pytest

# Under pytest-xdist (`make test` runs two workers on two cores), each worker
# gets one core's share: one thread for torch, BLAS and our ParallelMap, so
# two workers do not oversubscribe the machine. Set before anything imports
# torch or numpy's BLAS.
if os.environ.get("PYTEST_XDIST_WORKER"):
    for _k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS",
               "LMAP_DRAKE_THREADS", "LMAP_TORCH_THREADS"):
        os.environ.setdefault(_k, "1")

from lmap_drake.scenario import LoadDefaultScenario  # noqa: E402


@pytest.fixture
def scenario():
    """The built-in default scenario (a fresh copy per test)."""
    return LoadDefaultScenario()
