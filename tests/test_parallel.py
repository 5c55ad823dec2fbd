"""Threads for independent work: the default follows the CPUs, or the share
an evaluation worker is given."""
import os
import threading

from lmap_drake.parallel import THREADS_ENV, DefaultWorkers, ParallelMap


def test_default_workers_follow_the_cpus_or_the_share_given(monkeypatch):
    monkeypatch.delenv(THREADS_ENV, raising=False)
    cpus = len(os.sched_getaffinity(0))
    assert DefaultWorkers() == cpus
    monkeypatch.setenv(THREADS_ENV, "1")
    assert DefaultWorkers() == 1
    monkeypatch.setenv(THREADS_ENV, str(cpus + 5))      # never more than the CPUs
    assert DefaultWorkers() == cpus
    monkeypatch.setenv(THREADS_ENV, "many")              # unreadable: ignored
    assert DefaultWorkers() == cpus


def test_parallel_map_keeps_the_order_and_uses_the_workers():
    seen = set()

    def f(x):
        seen.add(threading.get_ident())
        return x * x
    assert ParallelMap(f, range(20), workers=2) == [x * x for x in range(20)]
    assert ParallelMap(f, [3], workers=4) == [9]
