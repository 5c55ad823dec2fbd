"""``lmap-drake eval``: runs episodes of a scenario suite in worker
processes and writes the Table II-V analogues (see ``tables.py``).

Each worker process loads its own scenario and builds its own diagram and
models; an exception inside an episode becomes a record with status
``error`` (message and traceback) instead of ending the run. Records are
appended to ``episodes.jsonl`` as episodes finish, so an interrupted run
can be continued with ``resume=True`` (episodes whose latest record is not
an error are skipped) and the tables are rebuilt from all records.
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

from lmap_drake.evaluation import tables as T


def _init_worker(threads: int) -> None:
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
        from lmap_drake.evaluation.episode import RunEpisode
        from lmap_drake.scenario import LoadScenario
        scenario = LoadScenario(filename=suite_file, scenario_name=spec["scenario"],
                                scenario_text=[spec.get("scenario_text", "{}"),
                                               T.ScenarioOverride(spec)])
        record = dict(RunEpisode(scenario).record)
    except BaseException as err:  # noqa: BLE001 - recorded, not raised
        if isinstance(err, KeyboardInterrupt):
            raise
        record = {"status": "error", "message": f"{type(err).__name__}: {err}",
                  "traceback": traceback.format_exc(),
                  "wall_seconds": time.perf_counter() - t0}
    record["eval"] = dict(spec, suite_file=str(suite_file),
                          scenario_text=T.ScenarioOverride(spec))
    return record


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
    done = T.CompletedIds(T.ReadRecords(log)) if resume else set()
    todo = [s for s in specs if s["episode_id"] not in done]
    progress(f"{len(specs)} episode(s), {len(specs) - len(todo)} already in {log.name}; "
             f"running {len(todo)} with {workers} worker(s)")
    t_start = time.perf_counter()
    errors = []
    if todo:
        ctx = mp.get_context("spawn")
        with cf.ProcessPoolExecutor(max_workers=max(1, workers), mp_context=ctx,
                                    initializer=_init_worker,
                                    initargs=(threads_per_worker,)) as pool, \
                open(log, "a") as f:
            futures = {pool.submit(RunOneEpisode, s, str(suite_file)): s for s in todo}
            for k, fut in enumerate(cf.as_completed(futures), 1):
                spec = futures[fut]
                try:
                    rec = fut.result()
                except Exception as err:  # the worker process itself died
                    rec = {"status": "error", "message": f"worker: {type(err).__name__}: "
                           f"{err}", "wall_seconds": None,
                           "eval": dict(spec, suite_file=str(suite_file),
                                        scenario_text=T.ScenarioOverride(spec))}
                f.write(json.dumps(rec, default=_json_default) + "\n")
                f.flush()
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
    records = T.ReadRecords(log)
    files = T.WriteTables(records, out, threshold, notes=notes)
    progress(f"wrote {', '.join(['episodes.jsonl'] + files)} to {out} "
             f"({time.perf_counter() - t_start:.0f} s)")
    return {"ran": len(todo), "skipped": len(specs) - len(todo), "errors": errors,
            "files": files}
