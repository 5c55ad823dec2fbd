"""Where ``lmap-drake eval`` runs its episodes: ``pool`` (the default:
worker processes on this machine, nothing to install) or ``ray`` (tasks
on a local Ray instance or a Ray cluster; ``pip install -e '.[ray]'``).

One small interface for both::

    with MakeEngine("ray", workers=2) as engine:
        for i, result in engine.Imap(fn, jobs):
            ...

``Imap`` yields each job's index and ``fn(*jobs[i])`` (or the exception
that stopped its worker: a crash, a lost node) in the order the jobs
finish. ``engine.slots`` is how many run at once (the cluster's CPUs for
Ray). Leaving the ``with`` block on an exception (Ctrl-C, SIGTERM, an
error while writing) kills the pool's workers or cancels the Ray tasks,
and stops a Ray instance the engine started.

``fn`` and the jobs cross process (and, on a cluster, machine) boundaries
by pickling: pass specs and paths, never Drake objects (diagrams do not
pickle); each job builds its own Diagram. Every worker runs one torch /
BLAS thread per job (``InitWorker``).
"""
from __future__ import annotations

import concurrent.futures as cf
import multiprocessing as mp
import os
import subprocess
import sys
import time
from typing import Any, Callable, Iterator, Protocol, Sequence

from lmap_drake.errors import InputError
from lmap_drake.parallel import THREADS_ENV

REAPER = os.path.join(os.path.dirname(os.path.abspath(__file__)), "ray_reaper.py")

ENGINES = ("pool", "ray")
RAY_REQUIREMENT = "ray==2.60.0"
RAY_INSTALL = "pip install -e '.[ray]'"
# A local Ray instance keeps its object store small: records are a few kB.
LOCAL_OBJECT_STORE_BYTES = 200 * 1024 ** 2


class EngineError(InputError):
    """An engine cannot be used as asked (Ray missing, no cluster at the
    address); the message says what to do. Exit code 2."""


class Engine(Protocol):
    name: str
    slots: int

    def __enter__(self) -> "Engine": ...

    def __exit__(self, exc_type, exc, tb) -> None: ...

    def Imap(self, fn: Callable, jobs: Sequence[tuple]) -> Iterator[tuple[int, Any]]: ...


# ------------------------------------------------------------ worker setup
def _WatchParent(parent: int) -> None:
    """Exits this worker when the parent process is gone (reparented)."""
    import threading

    def watch():
        while True:
            time.sleep(1.0)
            if os.getppid() != parent:
                os._exit(1)
    threading.Thread(target=watch, name="parent-watchdog", daemon=True).start()


def _DieWithParent() -> None:
    """Linux: the kernel kills this process when its parent exits."""
    import signal
    try:
        import ctypes
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGKILL)      # PR_SET_PDEATHSIG
    except Exception:  # noqa: BLE001 - not Linux: the watchdog remains
        pass


def InitWorker(threads: int, parent: int | None = None) -> None:
    """``threads`` torch / BLAS threads in this worker (two workers on a
    two-core machine: one each); with ``parent``, die with that process."""
    if parent is not None:
        _DieWithParent()
        if os.getppid() != parent:          # the parent died before prctl
            os._exit(1)
        _WatchParent(parent)
    for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", THREADS_ENV):
        os.environ.setdefault(k, str(threads))
    try:
        import torch
        torch.set_num_threads(threads)
    except Exception:
        pass


# ------------------------------------------------------------------- pool
class PoolEngine:
    """``workers`` spawned processes on this machine; they die with it."""
    name = "pool"

    def __init__(self, workers: int = 2, threads: int = 1):
        self.slots = max(1, int(workers))
        self.threads = threads
        self._pool = None

    def __enter__(self) -> "PoolEngine":
        self._pool = cf.ProcessPoolExecutor(
            max_workers=self.slots, mp_context=mp.get_context("spawn"),
            initializer=InitWorker, initargs=(self.threads, os.getpid()))
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        pool, self._pool = self._pool, None
        if exc_type is None:
            pool.shutdown(wait=True)
            return
        # Ctrl-C, SIGTERM or an error here: no orphaned workers.
        for p in list((getattr(pool, "_processes", None) or {}).values()):
            p.kill()
        pool.shutdown(wait=False, cancel_futures=True)

    def Imap(self, fn, jobs):
        futures = {self._pool.submit(fn, *job): i for i, job in enumerate(jobs)}
        for fut in cf.as_completed(futures):
            try:
                out = fut.result()
            except Exception as err:  # noqa: BLE001 - the worker process died
                out = err
            yield futures[fut], out


# -------------------------------------------------------------------- ray
def ImportRay(local: bool = True):
    """``import ray``, or EngineError with the install line. ``local``: a
    Ray instance started here listens on the loopback interface only
    (Ray's own switch for a single-machine instance; it has to be set
    before Ray is imported)."""
    import sys
    if local and "ray" not in sys.modules:
        os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
    try:
        import ray
    except ImportError:
        raise EngineError(f"--engine ray needs Ray, an optional extra: {RAY_INSTALL} "
                          f"(or pip install '{RAY_REQUIREMENT}'); the default --engine "
                          "pool needs nothing more") from None
    return ray


def CheckAddress(address: str, timeout: float = 5.0) -> None:
    """EngineError unless something answers at a ``host:port`` Ray
    address (``auto`` and ``ray://`` addresses are left to Ray); Ray itself
    would wait for minutes."""
    import socket
    if address == "auto" or "://" in address:
        return
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise EngineError(f"--address must be HOST:PORT (the head's `ray start --head` "
                          f"address, e.g. 10.0.0.5:6379) or auto, got {address!r}")
    target = address
    try:   # Ray maps localhost to the node's address, as ray.init does
        from ray._private.services import canonicalize_bootstrap_address
        target = canonicalize_bootstrap_address(address) or address
    except Exception:  # noqa: BLE001 - fall back to the address as given
        pass
    h, _, p = target.rpartition(":")
    try:
        socket.create_connection((h, int(p)), timeout=timeout).close()
    except OSError as err:
        raise EngineError(f"no Ray cluster answers at --address {address} "
                          f"({err.strerror or err}); start one with `ray start --head` "
                          "(README: Evaluation on Ray) or leave out --address for a "
                          "local instance") from None


def _SignalHandlers() -> dict:
    import signal
    return {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}


def _RestoreSignalHandlers(handlers: dict) -> None:
    """``ray.init`` installs its own SIGTERM handler (a stack dump, then
    exit, skipping our cleanup): put back the command's (SIGTERM as Ctrl-C,
    ``errors.RunMain``) so tasks are cancelled and the instance stopped."""
    import signal
    for sig, h in handlers.items():
        try:
            signal.signal(sig, h if h is not None else signal.SIG_DFL)
        except (ValueError, TypeError):        # not the main thread
            pass


def _RayTask(fn, threads: int, *args):
    """A Ray task: one torch / BLAS thread in this worker, then ``fn``."""
    InitWorker(threads)
    return fn(*args)


def StartReaper() -> subprocess.Popen | None:
    """``ray_reaper.py`` watching this process, started before ``ray.init``
    of a local instance: when this process dies (SIGKILL included), the
    processes it started (the Ray node: GCS, raylet, agents, workers) are
    terminated within seconds. None where there is no ``/proc``."""
    if not os.path.isdir("/proc"):
        return None
    return subprocess.Popen([sys.executable, REAPER, str(os.getpid())],
                            stdin=subprocess.DEVNULL, start_new_session=True)


def _StopReaper(reaper: subprocess.Popen | None) -> None:
    if reaper is not None:
        reaper.kill()
        reaper.wait()


class RayEngine:
    """Ray tasks (one CPU each) on a local instance with ``workers`` CPUs,
    or on the cluster at ``address``. A Ray session already initialised
    in this process is used as it is (and left running)."""
    name = "ray"

    def __init__(self, workers: int = 2, threads: int = 1, address: str | None = None):
        self.workers, self.threads, self.address = max(1, int(workers)), threads, address
        self.slots = self.workers
        self._ray = self._task = None
        self._own = False
        self._reaper = None
        self._pending: dict = {}

    def __enter__(self) -> "RayEngine":
        import logging
        ray = self._ray = ImportRay(local=self.address is None)
        if not ray.is_initialized():
            if self.address:
                CheckAddress(self.address)
                kw = dict(address=self.address, logging_level=logging.WARNING)
            else:
                kw = dict(num_cpus=self.workers, object_store_memory=LOCAL_OBJECT_STORE_BYTES,
                          logging_level=logging.ERROR)
            handlers = _SignalHandlers()
            self._reaper = None if self.address else StartReaper()
            try:
                ray.init(include_dashboard=False, **kw)
            except Exception as err:  # noqa: BLE001 - one line for the CLI
                where = f"the Ray cluster at {self.address}" if self.address else \
                    "a local Ray instance"
                hint = ("; a cluster with token authentication needs RAY_AUTH_MODE=token "
                        "and its ~/.ray/auth_token here (README: A Ray cluster)"
                        if self.address else "")
                _StopReaper(self._reaper)
                raise EngineError(f"cannot connect to {where}: "
                                  f"{' '.join(str(err).split())[:300]}{hint}") from None
            finally:
                _RestoreSignalHandlers(handlers)
            self._own = True
        self.slots = max(1, int(ray.cluster_resources().get("CPU", 1)))
        self._task = ray.remote(num_cpus=1, max_retries=1)(_RayTask)
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        ray = self._ray
        if exc_type is not None:
            for ref in list(self._pending):
                try:
                    ray.cancel(ref, force=True)
                except Exception:  # noqa: BLE001 - finished meanwhile
                    pass
        self._pending = {}
        if self._own:
            ray.shutdown()
            self._own = False
        _StopReaper(self._reaper)         # the node is down: nothing left to reap
        self._reaper = None

    def Imap(self, fn, jobs):
        ray = self._ray
        pending = self._pending = {self._task.remote(fn, self.threads, *job): i
                                   for i, job in enumerate(jobs)}
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                i = pending.pop(ref)
                try:
                    out = ray.get(ref)
                except Exception as err:  # noqa: BLE001 - worker crash, lost node
                    out = err
                yield i, out


def MakeEngine(name: str = "pool", workers: int = 2, threads: int = 1,
               address: str | None = None) -> Engine:
    """The engine called ``name`` (``ENGINES``)."""
    if name == "pool":
        if address:
            raise EngineError("--address needs --engine ray")
        return PoolEngine(workers, threads)
    if name == "ray":
        return RayEngine(workers, threads, address)
    raise EngineError(f"--engine must be one of {', '.join(ENGINES)}, got {name!r}")
