"""``lmap-drake eval``: runs episodes of a scenario suite in worker
processes and writes the Table II-V analogues (see ``tables.py``).

Each worker process loads its own scenario and builds its own diagram and
models; an exception inside an episode becomes a record with status
``error`` (message and traceback) instead of ending the run. Records are
appended to ``episodes.jsonl`` as episodes finish, so an interrupted run
can be continued with ``resume=True`` (episodes whose latest record is not
an error are skipped) and the tables are rebuilt from all records.

Each episode id carries a hash of its resolved scenario (``ResolveSpecs``):
resuming with other settings (``--scenario_text``, an edited suite) is
refused instead of mixing results. Torn lines of a killed run are set aside
to ``episodes.jsonl.torn`` and their episodes re-run. Workers die with the
parent (``PR_SET_PDEATHSIG`` on Linux, and a watchdog on the parent pid).
"""
from __future__ import annotations

import concurrent.futures as cf
import json
import multiprocessing as mp
import os
import time
import traceback
from pathlib import Path
from typing import Callable

from lmap_drake.errors import InputError
from lmap_drake.evaluation import tables as T


class EvalConflict(InputError):
    """``--resume`` would mix results of different settings."""


def ScenarioHash(scenario) -> str:
    """8 hex digits of the resolved scenario (all fields, YAML-dumped)."""
    import hashlib

    from pydrake.common.yaml import yaml_dump_typed

    from lmap_drake.scenario import Scenario
    return hashlib.sha1(yaml_dump_typed(scenario, schema=Scenario).encode()).hexdigest()[:8]


def _LoadSpec(spec: dict, suite_file: str):
    from lmap_drake.scenario import LoadScenario
    return LoadScenario(filename=suite_file, scenario_name=spec["scenario"],
                        scenario_text=[spec.get("scenario_text", "{}"),
                                       T.ScenarioOverride(spec)])


def ResolveSpecs(specs: list[dict], suite_file: str | Path, strict: bool = True) -> None:
    """Loads each spec's scenario and sets ``scenario_hash`` and the
    ``episode_id`` that includes it. ``strict``: a scenario that does not
    load raises (ScenarioError); otherwise that spec is left as it is (its
    worker records the error)."""
    for spec in specs:
        if spec.get("scenario_hash"):
            continue
        try:
            spec["scenario_hash"] = ScenarioHash(_LoadSpec(spec, str(suite_file)))
        except Exception:
            if strict:
                raise
            continue
        spec["episode_id"] = T.EpisodeId(spec)


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


def _init_worker(threads: int, parent: int | None = None) -> None:
    if parent is not None:
        _DieWithParent()
        if os.getppid() != parent:          # the parent died before prctl
            os._exit(1)
        _WatchParent(parent)
    # Two workers on a two-core machine: one BLAS/torch thread each.
    for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(k, str(threads))
    try:
        import torch
        torch.set_num_threads(threads)
    except Exception:
        pass


def RunOneEpisode(spec: dict, suite_file: str) -> dict:
    """Runs one spec in this process; never raises (errors become records)."""
    t0 = time.perf_counter()
    try:
        from lmap_drake.episode import RunSimEpisode
        scenario = _LoadSpec(spec, suite_file)
        if spec.get("scenario_hash") and ScenarioHash(scenario) != spec["scenario_hash"]:
            raise EvalConflict(f"{suite_file} changed while the evaluation ran: "
                               f"{spec['scenario']} no longer matches {spec['episode_id']}")
        record = dict(RunSimEpisode(scenario).record)
    except BaseException as err:  # noqa: BLE001 - recorded, not raised
        if isinstance(err, KeyboardInterrupt):
            raise
        record = {"status": "error", "message": f"{type(err).__name__}: {err}",
                  "traceback": traceback.format_exc(),
                  "wall_seconds": time.perf_counter() - t0}
    record["eval"] = _EvalEntry(spec, suite_file)
    return record


def _EvalEntry(spec: dict, suite_file) -> dict:
    return dict(spec, suite_file=str(suite_file), scenario_text=T.ScenarioOverride(spec),
                base_scenario_text=spec.get("scenario_text", "{}"))


def _json_default(x):
    try:
        return float(x)
    except Exception:
        return str(x)


def RunEvaluation(specs: list[dict], suite_file: str | Path, out: str | Path,
                  workers: int = 2, resume: bool = False,
                  progress: Callable[[str], None] = print,
                  threshold: float = T.VISIBILITY_SUCCESS, notes: str = "",
                  threads_per_worker: int = 1) -> dict:
    """Runs ``specs`` (skipping finished ones with ``resume``), appends to
    ``out/episodes.jsonl`` and writes the tables. Returns a summary."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    log = out / "episodes.jsonl"
    if log.exists() and not resume:
        raise FileExistsError(f"{log} exists: pass --resume to continue it, or choose "
                              "another --output")
    ResolveSpecs(specs, suite_file, strict=False)
    done: set = set()
    if resume:
        torn = T.RepairLog(log)
        if torn:
            progress(f"set aside {torn} torn line(s) of {log.name} to {log.name}.torn; "
                     f"their episodes run again")
        records = T.ReadRecords(log)
        conflicts = T.ResumeConflicts(records, specs)
        if conflicts:
            raise EvalConflict(
                f"--resume would mix results of different settings in {log}: "
                f"{conflicts[0]}" + (f" (and {len(conflicts) - 1} more)"
                                     if len(conflicts) > 1 else "")
                + "; use another --output for these settings")
        done = T.CompletedIds(records)
    todo = [s for s in specs if s["episode_id"] not in done]
    progress(f"{len(specs)} episode(s), {len(specs) - len(todo)} already in {log.name}; "
             f"running {len(todo)} with {workers} worker(s)")
    t_start = time.perf_counter()
    errors = []
    if todo:
        ctx = mp.get_context("spawn")
        pool = cf.ProcessPoolExecutor(max_workers=max(1, workers), mp_context=ctx,
                                      initializer=_init_worker,
                                      initargs=(threads_per_worker, os.getpid()))
        try:
            _RunPool(pool, todo, suite_file, log, errors, progress)
        except BaseException:
            # Ctrl-C, SIGTERM or an error here: no orphaned workers.
            for p in list((getattr(pool, "_processes", None) or {}).values()):
                p.kill()
            pool.shutdown(wait=False, cancel_futures=True)
            raise
        pool.shutdown(wait=True)
    records = T.ReadRecords(log)
    files = T.WriteTables(records, out, threshold, notes=notes)
    progress(f"wrote {', '.join(['episodes.jsonl'] + files)} to {out} "
             f"({time.perf_counter() - t_start:.0f} s)")
    return {"ran": len(todo), "skipped": len(specs) - len(todo), "errors": errors,
            "files": files}


def _RunPool(pool, todo: list[dict], suite_file, log: Path, errors: list,
             progress: Callable[[str], None]) -> None:
    """Submits ``todo`` and appends each record to ``log`` as it finishes
    (one write per line, flushed and synced)."""
    with open(log, "a") as f:
        futures = {pool.submit(RunOneEpisode, s, str(suite_file)): s for s in todo}
        for k, fut in enumerate(cf.as_completed(futures), 1):
            spec = futures[fut]
            try:
                rec = fut.result()
            except Exception as err:  # the worker process itself died
                rec = {"status": "error", "message": f"worker: {type(err).__name__}: "
                       f"{err}", "wall_seconds": None, "eval": _EvalEntry(spec, suite_file)}
            f.write(json.dumps(rec, default=_json_default) + "\n")
            f.flush()
            os.fsync(f.fileno())
            if rec.get("status") == "error":
                errors.append((spec["episode_id"], rec["message"]))
            o = rec.get("outcome") or {}
            extra = (f" vis {o.get('visibility_initial', 0):.2f}->"
                     f"{o.get('visibility_final', 0):.2f} safe={T.IsSafe(rec)}"
                     if o else f" {rec.get('message', '')[:200]}")
            wall = rec.get("wall_seconds")
            progress(f"[{k}/{len(todo)}] {spec['scenario']} {spec['method']} "
                     f"{T.DistanceLabel(spec['distance'])} seed {spec['seed']}: "
                     f"{rec.get('status')} in "
                     f"{'?' if wall is None else f'{wall:.1f}'} s;{extra}")
