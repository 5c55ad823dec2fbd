"""``lmap-drake eval --sweep FILE``: a grid of scenario overrides crossed
with the suite. Pure functions (the run is ``run_eval.RunSweep``).

The sweep file maps dotted scenario keys (fields of the ``Scenario``
dataclasses, ``lmap_drake/scenario.py``) to lists of values; several keys
make the cartesian product, in file order::

    planner.energy_weight: [0.0, 0.5, 1.0, 2.0]
    planner.num_grasps: [10, 15]          # optional: 4 x 2 = 8 grid points

Each grid point's values become one YAML override applied after the
eval-wide ``--scenario_text`` and after each method's own settings (a
swept ``planner.energy_weight`` wins over the lmap method's lambda = 1).
"""
from __future__ import annotations

import itertools
import math
import re
from pathlib import Path

import numpy as np

from lmap_drake.errors import InputError
from lmap_drake.evaluation import tables as T
from lmap_drake.evaluation.report import SaveFigure
from lmap_drake.limits import MAX_SCENARIO_BYTES, ReadBounded, TooLargeError

# Keys the method labels own: sweeping them would mislabel the tables.
RESERVED = {"planner.method": "choose methods with --methods"}
METRICS = {"visibility_final": "final visibility", "safe_fraction": "safe fraction",
           "success_fraction": "success fraction"}
_KEY = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")


class SweepError(InputError):
    """A bad sweep file; the message names the file and the key."""


def ParseSweep(text: str, where: str) -> list[tuple[str, list]]:
    """[(dotted key, values)] of a sweep file's text, checked for form:
    a non-empty map of dotted keys to non-empty lists of distinct values."""
    from lmap_drake.scenario import RawYaml, ScenarioError
    try:
        raw = RawYaml(text, where)
    except ScenarioError as err:
        raise SweepError(str(err)) from None
    if not isinstance(raw, dict) or not raw:
        raise SweepError(f"{where}: a sweep file maps dotted scenario keys to lists of "
                         f"values, e.g. 'planner.energy_weight: [0, 0.5, 1, 2]'")
    out = []
    for key, values in raw.items():
        if not isinstance(key, str) or not _KEY.match(key):
            raise SweepError(f"{where}: {key!r} is not a dotted scenario key such as "
                             f"planner.energy_weight")
        if key in RESERVED:
            raise SweepError(f"{where}: {key} cannot be swept ({RESERVED[key]})")
        if not isinstance(values, list) or not values:
            raise SweepError(f"{where}: {key} needs a non-empty list of values, e.g. "
                             f"[0, 0.5, 1], got {values!r}")
        dup = [v for i, v in enumerate(values) if v in values[:i]]     # 1 == 1.0
        if dup:
            raise SweepError(f"{where}: {key} lists {dup[0]!r} twice")
        out.append((key, values))
    keys = [k for k, _ in out]
    for a in keys:
        for b in keys:
            if b.startswith(a + "."):
                raise SweepError(f"{where}: {a} and {b} overlap (sweep one of them)")
    return out


def LoadSweep(path: str | Path) -> list[tuple[str, list]]:
    """``ParseSweep`` of a file; SweepError naming a missing or unreadable one."""
    path = Path(path)
    if not path.is_file():
        raise SweepError(f"sweep file not found: {path}")
    try:
        text = ReadBounded(path, MAX_SCENARIO_BYTES, "sweep file").decode("utf-8")
    except (OSError, UnicodeDecodeError, TooLargeError) as err:
        raise SweepError(f"cannot read sweep file {path}: {err}") from None
    return ParseSweep(text, str(path))


def GridPoints(sweep: list[tuple[str, list]]) -> list[dict]:
    """The cartesian product: [{dotted key: value}], first key slowest."""
    keys = [k for k, _ in sweep]
    return [dict(zip(keys, combo)) for combo in itertools.product(*(v for _, v in sweep))]


def OverrideText(point: dict) -> str:
    """A grid point as one flow-style YAML override (``--scenario_text`` form)."""
    import yaml
    nested: dict = {}
    for key, value in point.items():
        node = nested
        *parents, leaf = key.split(".")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return yaml.safe_dump(nested, default_flow_style=True, width=math.inf,
                          sort_keys=False).strip()


def _ValueLabel(v) -> str:
    if isinstance(v, list):
        return "_".join(_ValueLabel(x) for x in v) or "empty"
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)


def PointLabel(index: int, point: dict) -> str:
    """Folder name of a grid point: ``p00-energy_weight=0.5`` (the last
    part of each key; characters unsafe in file names become ``_``)."""
    parts = [f"{k.rsplit('.', 1)[-1]}={_ValueLabel(v)}" for k, v in point.items()]
    label = f"p{index:02d}-" + ",".join(parts)
    return re.sub(r"[^A-Za-z0-9._=,+-]", "_", label)[:120]


def CheckPoints(sweep: list[tuple[str, list]], where: str,
                base_text: str = "{}") -> list[dict]:
    """Loads the default scenario with ``base_text`` and each value alone,
    then with each grid point, so a bad key or value fails before anything
    runs with a message naming the file, the key and the value. Returns
    the grid points."""
    from lmap_drake.scenario import LoadScenario, ScenarioError
    for key, values in sweep:
        for v in values:
            try:
                LoadScenario(scenario_text=[base_text, OverrideText({key: v})])
            except ScenarioError as err:
                raise SweepError(f"{where}: {key} = {v!r}: "
                                 f"{str(err).replace('--scenario_text', 'the sweep')}") from None
    points = GridPoints(sweep)
    if len(sweep) > 1:
        for p in points:
            try:
                LoadScenario(scenario_text=[base_text, OverrideText(p)])
            except ScenarioError as err:
                raise SweepError(f"{where}: grid point {OverrideText(p)}: "
                                 f"{str(err).replace('--scenario_text', 'the sweep')}") from None
    return points


# -------------------------------------------------------------- summary
def PointMetrics(records: list[dict], threshold: float = T.VISIBILITY_SUCCESS) -> dict:
    """The main metrics of one grid point's records (latest per episode):
    mean final visibility, safe fraction, success fraction (safe and final
    visibility >= ``threshold``), over all methods (``all``) and per method."""
    latest = list(T.LatestRecords(records).values())

    def metrics(rs):
        ok = [r for r in rs if r.get("status") != "error" and r.get("outcome")]
        n = len(ok)
        safe = [T.IsSafe(r) for r in ok]
        vis = [float(r["outcome"]["visibility_final"]) for r in ok]
        success = [s and v >= threshold for s, v in zip(safe, vis)]
        return {"n": n, "n_errors": len(rs) - n,
                "visibility_final": float(np.mean(vis)) if n else None,
                "scored_visibility": float(np.mean([T.ScoredVisibility(r) for r in ok]))
                if n else None,
                "safe_fraction": sum(safe) / n if n else None,
                "success_fraction": sum(success) / n if n else None}
    by: dict[str, list] = {}
    for r in latest:
        by.setdefault(r["eval"]["method"], []).append(r)
    order = sorted(by, key=lambda m: T.METHODS.index(m) if m in T.METHODS else 99)
    return {"all": metrics(latest), "by_method": {m: metrics(by[m]) for m in order}}


def Summary(sweep: list[tuple[str, list]], points: list[dict], labels: list[str],
            records: list[list[dict]], threshold: float, sweep_file: str) -> dict:
    """The sweep's summary JSON: keys, and per grid point its values,
    folder and ``PointMetrics``."""
    return {"sweep_file": str(sweep_file), "keys": [k for k, _ in sweep],
            "threshold": threshold,
            "points": [dict(label=lab, folder=lab, values=p, override=OverrideText(p),
                            **PointMetrics(rs, threshold))
                       for p, lab, rs in zip(points, labels, records)]}


def SaveSummaryPlot(summary: dict, path: Path) -> str:
    """The main metrics against the swept values (one line per method and
    one for all methods); x is the value for one numeric key, else the
    grid points in order. Returns the file name."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    pts = summary["points"]
    keys = summary["keys"]
    numeric = len(keys) == 1 and all(
        isinstance(p["values"][keys[0]], (int, float)) and not isinstance(
            p["values"][keys[0]], bool) for p in pts)
    if numeric:
        x = [float(p["values"][keys[0]]) for p in pts]
        ticks, xlabel = None, keys[0]
    else:
        x = list(range(len(pts)))
        ticks = ["\n".join(f"{k.rsplit('.', 1)[-1]}={_ValueLabel(v)}"
                           for k, v in p["values"].items()) for p in pts]
        xlabel = ", ".join(keys)
    methods = []
    for p in pts:
        methods += [m for m in p["by_method"] if m not in methods]
    fig, axes = plt.subplots(1, len(METRICS), figsize=(4.2 * len(METRICS), 3.6))
    for ax, (k, name) in zip(axes, METRICS.items()):
        for m in methods:
            y = [np.nan if (p["by_method"].get(m) or {}).get(k) is None
                 else p["by_method"][m][k] for p in pts]
            ax.plot(x, y, marker="o", label=m)
        if len(methods) > 1:
            y = [np.nan if p["all"][k] is None else p["all"][k] for p in pts]
            ax.plot(x, y, "k--", marker="s", label="all methods")
        ax.set_ylim(-0.03, 1.05)
        ax.set_title(name)
        ax.set_xlabel(xlabel)
        if ticks is not None:
            ax.set_xticks(x, ticks, fontsize=7)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"sweep {Path(summary['sweep_file']).name} "
                 f"(success: safe and final visibility >= {summary['threshold']:g})",
                 fontsize=9)
    return SaveFigure(fig, Path(path))
