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


# The files that take longest (about a minute each on 2 cores: the twin's full
# episodes, the Ray engine, the simulated episodes) go first, so that with
# two workers (`--dist loadfile`) neither is left with one of them at the end.
SLOW_FILES_FIRST = (
    "twin/test_twin.py",
    "evaluation/test_engines.py",
    "episode/test_episode_simulation.py",
    "test_cli.py",
    "plants/test_multi.py",
    "episode/test_episode_hardware.py",
)


def pytest_collection_modifyitems(session, config, items):
    def rank(item):
        path = item.nodeid.split("::")[0].removeprefix("tests/")
        return SLOW_FILES_FIRST.index(path) if path in SLOW_FILES_FIRST else len(SLOW_FILES_FIRST)
    items.sort(key=rank)     # stable: the order within a file, and of the rest, is kept
