"""``lmap-drake eval``: runs episodes of a scenario suite on an engine
(``engines.py``: worker processes on this machine, or Ray tasks) and
writes the Table II-V analogues (``tables.py``, ``report.py``); ``RunSweep`` does it
for every point of a grid of scenario overrides (``sweep.py``).

Each worker loads its own scenario and builds its own diagram and models;
an exception inside an episode becomes a record with status ``error``
(message and traceback) instead of ending the run. Records are appended
to ``episodes.jsonl`` as episodes finish (whichever engine ran them), so
an interrupted run can be continued with ``resume=True`` (episodes whose
latest record is not an error are skipped) and the tables are rebuilt
from all records.

Each episode id carries a hash of its resolved scenario (``ResolveSpecs``):
resuming with other settings (``--scenario_text``, an edited suite) is
refused instead of mixing results. Torn lines of a killed run are set aside
to ``episodes.jsonl.torn`` and their episodes re-run. Pool workers die with
the parent (``PR_SET_PDEATHSIG`` on Linux, and a watchdog on the parent
pid); Ray tasks are cancelled when the run stops.
"""
from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
import tempfile
import time
import traceback
from pathlib import Path
from typing import Callable

from lmap_drake.errors import InputError
from lmap_drake.plants.multi import MULTI_KINDS, NumPlantFruits
from lmap_drake.evaluation import progress as P
from lmap_drake.evaluation import report as R
from lmap_drake.evaluation import tables as T
from lmap_drake.evaluation.engines import InitWorker as _init_worker  # noqa: F401
from lmap_drake.evaluation.engines import MakeEngine


class EvalConflict(InputError):
    """``--resume`` would mix results of different settings."""


class EvalExists(InputError, FileExistsError):
    """``episodes.jsonl`` exists and ``--resume`` was not given."""


class PlantKindError(InputError):
    """A suite scene whose plant an episode cannot run (the placeholder)."""


# Plant kinds an episode runs on (``plant_scene.kind``); ``placeholder`` has
# no leaf and no fruit to reveal.
EVAL_KINDS = ("procedural",) + MULTI_KINDS   # kinds with a simulated leaf to move


def ScenarioHash(scenario) -> str:
    """8 hex digits of the resolved scenario (all fields, YAML-dumped)."""
    from pydrake.common.yaml import yaml_dump_typed

    from lmap_drake.scenario import Scenario
    return hashlib.sha1(yaml_dump_typed(scenario, schema=Scenario).encode()).hexdigest()[:8]


@functools.lru_cache(maxsize=4)
def SuiteEntries(suite_text: str) -> dict[str, str]:
    """Each top-level scenario of a suite's YAML as its own YAML text (the
    entry's map, cut from the text by the parser's marks): loading one
    scenario then parses that entry, not the whole suite (a 250-scene suite
    is 180 kB). Empty when the text does not parse."""
    import textwrap

    import yaml
    try:
        root = yaml.compose(suite_text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    except yaml.YAMLError:
        return {}
    if not isinstance(root, yaml.MappingNode):
        return {}
    out = {}
    for key, value in root.value:
        if not isinstance(key, yaml.ScalarNode) or value.start_mark.index is None:
            continue
        body = suite_text[value.start_mark.index:value.end_mark.index]
        out[key.value] = textwrap.dedent(" " * value.start_mark.column + body)
    return out


def _LoadSpec(spec: dict, suite_file: str, suite_text: str | None = None):
    """The spec's scenario: suite entry, eval-wide ``scenario_text``, the
    method's override, then a sweep point's override (``sweep_text``).
    With ``suite_text`` (``suite_file``'s text) only the entry is parsed
    (``SuiteEntries``); anything it cannot load is loaded from the file,
    whose error names the file and the key."""
    from lmap_drake.scenario import LoadScenario
    texts = [spec.get("scenario_text", "{}"), T.ScenarioOverride(spec)]
    if spec.get("sweep_text"):
        texts.append(spec["sweep_text"])
    entry = SuiteEntries(suite_text).get(spec["scenario"]) if suite_text else None
    if entry and entry.strip() not in ("", "{}", "null", "~"):
        try:
            return LoadScenario(scenario_text=[entry] + texts)
        except Exception:  # noqa: BLE001 - the full load below says why
            pass
    return LoadScenario(filename=suite_file, scenario_name=spec["scenario"],
                        scenario_text=texts)


def ResolveSpecs(specs: list[dict], suite_file: str | Path, strict: bool = True,
                 kinds: tuple | None = None) -> None:
    """Loads each spec's scenario and sets ``scenario_hash`` and the
    ``episode_id`` that includes it. ``strict``: a scenario that does not
    load raises (ScenarioError), and with ``kinds`` one whose
    ``plant_scene.kind`` is not among them (PlantKindError naming the
    scene); otherwise that spec is left as it is (its worker records the
    error)."""
    try:
        suite_text = Path(suite_file).read_text()
    except (OSError, UnicodeDecodeError):
        suite_text = None           # the loads below name the file's problem
    for spec in specs:
        if spec.get("scenario_hash"):
            continue
        try:
            scenario = _LoadSpec(spec, str(suite_file), suite_text)
            if kinds is not None and scenario.plant_scene.kind not in kinds:
                raise PlantKindError(
                    f"scenario {spec['scenario']} of {suite_file} has plant_scene.kind: "
                    f"{scenario.plant_scene.kind}, which eval cannot run (a stand-in with "
                    f"no leaf to move); eval needs plant_scene.kind "
                    f"{' or '.join(kinds)}")
            spec["scenario_hash"] = ScenarioHash(scenario)
            if scenario.plant_scene.kind in MULTI_KINDS and scenario.planner.targets == "all":
                spec["targets"] = NumPlantFruits(scenario.plant_scene)   # for the estimate
        except Exception:
            if strict:
                raise
            continue
        spec["episode_id"] = T.EpisodeId(spec)


def _SuiteCopy(suite_file: str, suite_text: str) -> str:
    """A path on this machine holding ``suite_text``: ``suite_file`` when it
    does (always, on the machine that started the run), else a copy in the
    temp folder (a Ray worker on another node, or a suite edited since)."""
    try:
        if Path(suite_file).read_text() == suite_text:
            return suite_file
    except (OSError, UnicodeDecodeError):
        pass
    digest = hashlib.sha1(suite_text.encode()).hexdigest()[:16]
    folder = Path(tempfile.gettempdir()) / "lmap_drake_suites"
    folder.mkdir(exist_ok=True)
    path = folder / f"{digest}.yaml"
    if not path.exists():
        tmp = path.with_name(f".{digest}.{os.getpid()}.tmp")
        tmp.write_text(suite_text)
        os.replace(tmp, path)
    return str(path)


def RunOneEpisode(spec: dict, suite_file: str, suite_text: str | None = None) -> dict:
    """Runs one spec in this process; never raises (errors become records).
    ``suite_text``: the suite as the run started, for workers that cannot
    read ``suite_file`` (the record names ``suite_file`` either way).
    ``cpu_seconds``: this process's CPU time for the episode (its cost in
    core-seconds, whatever else the machine ran)."""
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        from lmap_drake.episode import RunSimEpisode
        local = suite_file if suite_text is None else _SuiteCopy(suite_file, suite_text)
        scenario = _LoadSpec(spec, local, suite_text)
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
    record["cpu_seconds"] = time.process_time() - c0
    record["eval"] = _EvalEntry(spec, suite_file)
    return record


def _EvalEntry(spec: dict, suite_file) -> dict:
    return dict(spec, suite_file=str(suite_file), scenario_text=T.ScenarioOverride(spec),
                base_scenario_text=spec.get("scenario_text", "{}"))


def JsonDefault(x):
    try:
        return float(x)
    except Exception:
        return str(x)


def _Check(specs: list[dict], out: Path, resume: bool) -> tuple[Path, list[dict]]:
    """Refuses, writing nothing, an existing log without ``resume``, a log
    that is not a file, and with ``resume`` mixed settings. Returns the log
    and its records."""
    log = out / "episodes.jsonl"
    if (log.exists() or log.is_symlink()) and not log.is_file():
        raise EvalExists(f"{log} exists and is not a file")
    if log.exists() and not resume:
        raise EvalExists(f"{log} exists: pass --resume to continue it, or choose "
                         "another --output")
    records = T.ReadRecords(log) if resume else []
    conflicts = T.ResumeConflicts(records, specs)
    if conflicts:
        raise EvalConflict(
            f"--resume would mix results of different settings in {log}: "
            f"{conflicts[0]}" + (f" (and {len(conflicts) - 1} more)"
                                 if len(conflicts) > 1 else "")
            + "; use another --output for these settings")
    return log, records


def _Prepare(specs: list[dict], log: Path, records: list[dict], resume: bool,
             progress: Callable[[str], None]) -> tuple[list[dict], list[dict]]:
    """One checked output folder before anything runs: creates it; with
    ``resume`` sets torn lines aside. Returns (specs still to run, records
    already there)."""
    log.parent.mkdir(parents=True, exist_ok=True)
    done: set = set()
    if resume:
        torn = T.RepairLog(log)
        if torn:
            progress(f"set aside {torn} torn line(s) of {log} to {log.name}.torn (as they "
                     f"were, byte for byte); their episodes run again")
            records = T.ReadRecords(log)
        done = T.CompletedIds(records)
    return [s for s in specs if s["episode_id"] not in done], records


def EvalOptions(scenarios: int, seed: int, scenario_file, scenario_names: str,
                methods: list[str], distances: list[float], random_seeds: int,
                scenario_text: str, sweep_text: str | None) -> dict:
    """What an evaluation is (kept in its folder's marker; ``--resume`` with
    other values is refused, naming the option): keys are the ``eval``
    options. ``--workers``, ``--engine``, ``--address`` and
    ``--visibility_success`` may change."""
    return {"scenarios": int(scenarios), "seed": int(seed),
            "scenario_file": None if scenarios else str(Path(scenario_file).resolve()),
            "scenario_names": [n for n in scenario_names.split(",") if n],
            "methods": sorted(methods),
            "distances": sorted(float(d) for d in distances)         # baselines only
            if set(methods) & set(T.BASELINES) else [],
            "random_seeds": int(random_seeds) if "random" in methods else 0, "scenario_text": _Parsed(scenario_text) or {},
            "sweep": None if sweep_text is None else _Parsed(sweep_text)}


def _Parsed(text: str):
    """YAML text as JSON-able data (the text itself when it does not parse)."""
    import yaml
    try:
        return json.loads(json.dumps(yaml.safe_load(text), default=str))
    except yaml.YAMLError:
        return text


def HasRecords(folder: Path) -> bool:
    """Whether ``folder`` (or a sweep point folder in it) holds a record."""
    return any(p.is_file() and p.stat().st_size > 0
               for p in [Path(folder) / "episodes.jsonl",
                         *Path(folder).glob("*/episodes.jsonl")])


def _ProgressLine(k: int, n: int, spec: dict, rec: dict, eta: float | None) -> str:
    o = rec.get("outcome") or {}
    extra = (f" vis {o.get('visibility_initial', 0):.2f}->"
             f"{o.get('visibility_final', 0):.2f} safe={T.IsSafe(rec)}"
             if o else f" {rec.get('message', '')[:200]}")
    wall = rec.get("wall_seconds")
    point = f"{spec['sweep_point']} " if spec.get("sweep_point") else ""
    return (f"[{k}/{n}] {point}{spec['scenario']} {spec['method']} "
            f"{T.DistanceLabel(spec['distance'])} seed {spec['seed']}: "
            f"{rec.get('status')} in {'?' if wall is None else f'{wall:.1f}'} s;{extra}"
            + ("" if eta is None else f"; eta {P.Duration(eta)}"))


def _WriteOnce(path: Path, text: str) -> None:
    if not path.exists():
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_text(text)
        os.replace(tmp, path)


def _RunGroups(groups: list[tuple[Path, list[dict]]], suite_file: str | Path,
               engine: str, workers: int, address: str | None, threads: int,
               resume: bool, progress: Callable[[str], None],
               bar: bool | None, before: Callable[[], None] = lambda: None) -> dict:
    """Runs the specs of every (output folder, specs) group on one engine,
    appending each record to its group's ``episodes.jsonl`` as it finishes
    (one write per line, flushed and synced). Everything that can be
    refused is checked before the engine starts, and before ``before()``
    (which writes the run's own files)."""
    all_specs = [s for _, g in groups for s in g]
    ResolveSpecs(all_specs, suite_file, strict=False)
    jobs, existing = [], []
    prepared = [_Check(specs, Path(out), resume) for out, specs in groups]
    before()
    for (out, specs), (log, records) in zip(groups, prepared):
        todo, records = _Prepare(specs, log, records, resume, progress)
        jobs += [(s, log) for s in todo]
        existing += records
    n_all = len(all_specs)
    progress(f"{n_all} episode(s), {n_all - len(jobs)} already recorded; running "
             f"{len(jobs)} on the {engine} engine")
    errors: list = []
    if not jobs:
        return {"ran": 0, "skipped": n_all, "errors": errors, "estimate": None}
    suite_text = Path(suite_file).read_text()
    args = [(s, str(suite_file), suite_text) for s, _ in jobs]
    with contextlib.ExitStack() as stack:
        eng = stack.enter_context(MakeEngine(engine, workers, threads, address))
        est = P.Estimate([s for s, _ in jobs], eng.slots, existing)
        progress(P.EstimateLine(est, eng.name))
        logs: dict[Path, object] = {}
        show = stack.enter_context(P.Progress(len(jobs), progress, enabled=bar))
        t0 = time.perf_counter()
        for k, (i, out) in enumerate(eng.Imap(RunOneEpisode, args), 1):
            spec, log = jobs[i]
            rec = out if isinstance(out, dict) else {
                "status": "error", "message": f"worker: {type(out).__name__}: {out}",
                "wall_seconds": None, "eval": _EvalEntry(spec, suite_file)}
            if log not in logs:
                logs[log] = stack.enter_context(open(log, "a"))
            f = logs[log]
            f.write(json.dumps(rec, default=JsonDefault) + "\n")
            f.flush()
            os.fsync(f.fileno())
            if rec.get("status") == "error":
                errors.append((spec["episode_id"], rec["message"]))
            show.Step()
            eta = P.EtaSeconds(k, len(jobs), time.perf_counter() - t0)
            show.Say(_ProgressLine(k, len(jobs), spec, rec, eta if k < len(jobs) else None))
    return {"ran": len(jobs), "skipped": n_all - len(jobs), "errors": errors,
            "estimate": est}


def RunEvaluation(specs: list[dict], suite_file: str | Path, out: str | Path,
                  workers: int = 2, resume: bool = False,
                  progress: Callable[[str], None] = print,
                  threshold: float = T.VISIBILITY_SUCCESS, notes: str = "",
                  threads_per_worker: int = 1, engine: str = "pool",
                  address: str | None = None, bar: bool | None = None) -> dict:
    """Runs ``specs`` (skipping finished ones with ``resume``) on ``engine``
    (``pool``: ``workers`` processes; ``ray``: a local instance with
    ``workers`` CPUs, or the cluster at ``address``), appends to
    ``out/episodes.jsonl`` and writes the tables. ``bar``: a progress bar
    on stderr (None: when it is a terminal). Returns a summary."""
    out = Path(out)
    t_start = time.perf_counter()
    summary = _RunGroups([(out, specs)], suite_file, engine, workers, address,
                         threads_per_worker, resume, progress, bar)
    files = R.WriteTables(T.ReadRecords(out / "episodes.jsonl"), out, threshold, notes=notes)
    progress(f"wrote {', '.join(['episodes.jsonl'] + files)} to {out} "
             f"({time.perf_counter() - t_start:.0f} s)")
    return dict(summary, files=files)


def RunSweep(point_specs: list[list[dict]], sweep, points: list[dict], labels: list[str],
             sweep_file: str | Path, suite_file: str | Path, out: str | Path,
             workers: int = 2, resume: bool = False,
             progress: Callable[[str], None] = print,
             threshold: float = T.VISIBILITY_SUCCESS, threads_per_worker: int = 1,
             engine: str = "pool", address: str | None = None,
             bar: bool | None = None) -> dict:
    """Runs every grid point's specs on one engine into ``out/<label>/``
    (episodes.jsonl and tables each), then writes ``sweep_summary.json``
    and ``sweep_summary.png`` (``sweep.Summary``) in ``out``."""
    from lmap_drake.evaluation import sweep as S
    out = Path(out)
    t_start = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    grid, kept = Path(sweep_file).read_text(), out / "sweep.yaml"
    if kept.exists() and kept.read_text() != grid:
        raise EvalConflict(f"{kept} is another grid than {sweep_file}: --resume would mix "
                           "sweeps; use another --output for this one")
    groups = [(out / lab, specs) for lab, specs in zip(labels, point_specs)]
    summary = _RunGroups(groups, suite_file, engine, workers, address, threads_per_worker,
                         resume, progress, bar, before=lambda: _WriteOnce(kept, grid))
    records = []
    for (folder, _), p in zip(groups, points):
        rs = T.ReadRecords(folder / "episodes.jsonl")
        records.append(rs)
        R.WriteTables(rs, folder, threshold, notes=f"Sweep point {S.OverrideText(p)} "
                      f"({Path(sweep_file).name}).")
    data = S.Summary(sweep, points, labels, records, threshold, str(sweep_file))
    (out / "sweep_summary.json").write_text(json.dumps(data, indent=2))
    files = ["sweep_summary.json", S.SaveSummaryPlot(data, out / "sweep_summary.png")]
    progress(f"wrote {len(labels)} grid point folder(s) ({labels[0]} ...) and "
             f"{', '.join(files)} to {out} ({time.perf_counter() - t_start:.0f} s)")
    return dict(summary, files=files, summary=data)
