"""Threads for independent work items (deformation per grasp, shape
completion per fruit): torch and the ARAP kernels release the GIL, so two
items run on two cores at once."""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterable, TypeVar

T = TypeVar("T")
R = TypeVar("R")


THREADS_ENV = "LMAP_DRAKE_THREADS"


def DefaultWorkers() -> int:
    """Threads for independent items: the CPUs this process may run on, or
    fewer when ``LMAP_DRAKE_THREADS`` says so (an evaluation worker sharing
    the machine with others gets its share)."""
    try:
        cpus = max(1, len(os.sched_getaffinity(0)))
    except AttributeError:                       # not on Linux
        cpus = max(1, os.cpu_count() or 1)
    try:
        share = int(os.environ.get(THREADS_ENV, "0"))
    except ValueError:
        share = 0
    return min(cpus, share) if share > 0 else cpus


def ParallelMap(fn: Callable[[T], R], items: Iterable[T], workers: int | None = None) -> list[R]:
    """``[fn(x) for x in items]`` over at most ``workers`` threads (default
    ``DefaultWorkers()``), in the order of ``items``; one item or one
    worker runs in the calling thread. The first exception is raised."""
    items = list(items)
    workers = min(len(items), workers or DefaultWorkers())
    if workers <= 1:
        return [fn(x) for x in items]
    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(fn, items))
