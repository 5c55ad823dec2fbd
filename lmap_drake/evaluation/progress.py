"""What an evaluation will cost and how far it is: the up-front estimate
(episodes, core-hours, wall time on the engine's slots) and the progress
bar with its ETA. Pure functions, and one small tqdm wrapper.

Per-episode cost: the medians of ``wall_seconds`` of the records already
in ``episodes.jsonl`` (per method) when resuming, otherwise
``EPISODE_CORE_SECONDS``. An episode runs on one core (one torch / BLAS
thread), so its wall time with every core busy is its cost in
core-seconds.
"""
from __future__ import annotations

import statistics
import sys
from typing import Callable, TextIO

# Core-seconds per episode by method: medians of ``cpu_seconds`` measured by
# ``scripts/bench_engines.py`` (scripts/bench_engines.json, _2.json) on this
# project's 2-core machine (shared; 2 workers; the default perception: segnet
# on the noisy L515 camera): 4 suite scenes x 3 repeats x 2 engines x 2
# sessions = 48 episodes each of lmap (20.6 s) and upward at 4 cm (13.8 s).
# random and min_overlap move like upward (no deformation prediction);
# lmap_lambda0 plans like lmap.
EPISODE_CORE_SECONDS = {"lmap": 21.0, "lmap_lambda0": 21.0, "upward": 14.0,
                        "random": 14.0, "min_overlap": 14.0}
DEFAULT_CORE_SECONDS = 21.0
# A multi-fruit episode revealing every fruit (``spec["targets"]`` fruits):
# about this many core-seconds per fruit, from the multi suite's first
# evaluation here (2-4 fruits, 3-6 FEM leaves: 143-304 s per episode).
MULTI_CORE_SECONDS_PER_TARGET = 75.0


def EpisodeCosts(records: list[dict]) -> dict[str, tuple[float, int]]:
    """method -> (median cost, count) of the finished (non-error) records;
    an episode's cost is its ``cpu_seconds`` (``wall_seconds`` in records
    made before that field)."""
    by: dict[str, list[float]] = {}
    for r in records:
        w = r.get("cpu_seconds") or r.get("wall_seconds")
        m = (r.get("eval") or {}).get("method")
        if r.get("status") == "error" or m is None or not isinstance(w, (int, float)) or w <= 0:
            continue
        by.setdefault(m, []).append(float(w))
    return {m: (statistics.median(v), len(v)) for m, v in by.items()}


def Estimate(specs: list[dict], slots: int, records: list[dict] = ()) -> dict:
    """Episodes, core-hours and wall hours on ``slots`` cores for ``specs``;
    per-method cost from ``records`` where they have that method, else
    ``EPISODE_CORE_SECONDS``; a spec with ``targets`` (fruits revealed in
    turn on a multi-fruit plant) costs ``MULTI_CORE_SECONDS_PER_TARGET``
    each. ``source`` says which."""
    measured = EpisodeCosts(list(records))
    core_s, used = 0.0, set()
    for s in specs:
        m = s.get("method")
        if s.get("targets"):         # a plant whose every fruit is revealed
            core_s += MULTI_CORE_SECONDS_PER_TARGET * int(s["targets"])
        elif m in measured:
            core_s += measured[m][0]
            used.add(m)
        else:
            core_s += EPISODE_CORE_SECONDS.get(m, DEFAULT_CORE_SECONDS)
    n_meas = sum(measured[m][1] for m in used)
    c = EPISODE_CORE_SECONDS
    source = (f"medians of {n_meas} finished record(s) in episodes.jsonl" if used
              else f"per-episode constants measured here: lmap {c['lmap']:.0f} s, "
              f"upward {c['upward']:.0f} s of one core")
    slots = max(1, int(slots))
    busy = max(1, min(slots, len(specs)))      # fewer episodes than slots: some idle
    return {"episodes": len(specs), "core_seconds": core_s, "core_hours": core_s / 3600.0,
            "slots": slots, "wall_seconds": core_s / busy, "source": source}


def Duration(seconds: float) -> str:
    """``'45 s'``, ``'12 min'``, ``'3.5 h'``."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 90 * 60:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def EstimateLine(est: dict, engine: str) -> str:
    """One line: episodes, core-hours, wall time on the engine's slots."""
    return (f"estimate: {est['episodes']} episode(s), {est['core_hours']:.2f} core-hours, "
            f"~{Duration(est['wall_seconds'])} on {est['slots']} {engine} slot(s) "
            f"({est['source']})")


def EtaSeconds(done: int, total: int, elapsed: float) -> float | None:
    """Remaining seconds at the mean rate so far (None before the first)."""
    if done <= 0:
        return None
    return elapsed / done * max(0, total - done)


class Progress:
    """A tqdm bar (episodes, rate, ETA) on ``file`` (stderr), shown when
    ``enabled`` (default: stderr is a terminal), with ``say`` printing a
    line above it. Use as a context manager; ``Step()`` after each episode."""

    def __init__(self, total: int, say: Callable[[str], None] = print,
                 enabled: bool | None = None, file: TextIO | None = None,
                 desc: str = "eval", unit: str = "ep"):
        self.total, self._say = total, say
        self.file = file or sys.stderr
        if enabled is None:
            enabled = bool(getattr(self.file, "isatty", lambda: False)())
        self.enabled = enabled and total > 0
        self.bar = None
        self._desc, self._unit = desc, unit

    def __enter__(self) -> "Progress":
        if self.enabled:
            from tqdm import tqdm
            self.bar = tqdm(total=self.total, desc=self._desc, unit=self._unit, file=self.file,
                            dynamic_ncols=True, mininterval=1.0, smoothing=0.0)
        return self

    def __exit__(self, *exc) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None

    def Say(self, msg: str) -> None:
        if self.bar is None:
            self._say(msg)
            return
        from tqdm import tqdm
        with tqdm.external_write_mode(file=self.file):
            self._say(msg)

    def Step(self) -> None:
        if self.bar is not None:
            self.bar.update(1)
