"""Functional core of ``lmap-drake eval``: episode specs, and the
aggregation of episode records (``episode.RunSimEpisode(...).record`` plus an ``eval``
entry naming the spec) into analogues of the paper's Tables II-V (written
as JSON, Markdown and bar charts by ``report``), and the ``episodes.jsonl``
record files. Pure functions on dicts; nothing here simulates.

Method labels: ``random``, ``upward``, ``min_overlap`` (baselines, one row
per move distance), ``lmap`` (lambda = 1) and ``lmap_lambda0`` (lambda = 0);
the LMAP rows choose their own distance (row key ``adaptive``).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

BASELINES = ("random", "upward", "min_overlap")
LMAP_METHODS = {"lmap": 1.0, "lmap_lambda0": 0.0}
METHODS = BASELINES + tuple(LMAP_METHODS)
DEFAULT_DISTANCES = (0.02, 0.04, 0.06, 0.08)
ADAPTIVE = "adaptive"
SHAPE_KEYS = ("chamfer_cm", "volume_err_cm3", "center_err_cm", "angle_err_deg")
# Table IV rows: paper name -> stage_seconds keys (first present wins).
STAGES = {
    "semantic_segmentation": ("segmentation_s",),
    "branch_completion": ("branch_completion_s", "branch_s"),
    "fruit_completion": ("shape_completion_s",),
    "generation_collision": ("generation_collision_s",),
    "deformation_simulation": ("deformation_s",),
    "visibility_checking": ("visibility_s",),
    "reestimation": ("reestimation_s",),
    "replanning": ("replanning_s",),
}
VISIBILITY_SUCCESS = 0.95


# ----------------------------------------------------------------- specs
def DistanceLabel(distance: float | None) -> str:
    """Row key of a move distance: ``'6cm'`` (``'adaptive'`` for None)."""
    if distance is None:
        return ADAPTIVE
    cm = round(100.0 * float(distance), 2)
    return f"{cm:g}cm"


def SpecKey(spec: dict) -> str:
    """What an episode is, without its settings: scenario|method|distance|seed."""
    return f"{spec['scenario']}|{spec['method']}|{DistanceLabel(spec['distance'])}|s{spec['seed']}"


def EpisodeId(spec: dict) -> str:
    """``SpecKey`` plus, once resolved (``run_eval.ResolveSpecs``), a short
    hash of the episode's resolved scenario (suite entry, ``--scenario_text``
    and the method's overrides): the same episode with other settings has
    another id."""
    h = spec.get("scenario_hash")
    return SpecKey(spec) + (f"|{h}" if h else "")


def ResumeConflicts(records: list[dict], specs: list[dict]) -> list[str]:
    """Why ``records`` (an ``episodes.jsonl``) cannot be continued with
    ``specs`` without mixing results of different settings: a recorded
    episode that is one of ``specs`` but was run on another resolved
    scenario (its id's hash differs), or records made with another
    eval-wide ``--scenario_text``. Empty when resuming is safe."""
    ids = {s["episode_id"] for s in specs}
    by_key = {SpecKey(s): s for s in specs}
    texts = {s.get("scenario_text", "{}") for s in specs}
    out = []
    for eid, r in LatestRecords(records).items():
        e = r.get("eval", {})
        try:
            key = SpecKey(e)
        except KeyError:
            continue
        if key in by_key and eid not in ids:
            out.append(f"{key}: recorded as {eid}, now {by_key[key]['episode_id']} "
                       f"(the resolved scenario differs)")
        elif "base_scenario_text" in e and texts and e["base_scenario_text"] not in texts:
            out.append(f"{eid}: recorded with --scenario_text {e['base_scenario_text']!r}, "
                       f"now {sorted(texts)[0]!r}")
    return out


def EpisodeSpecs(scenarios: list[str], methods=METHODS, distances=DEFAULT_DISTANCES,
                 random_seeds: int = 5, seed: int = 0, scenario_text: str = "{}") -> list[dict]:
    """One spec per episode: the Random baseline ``random_seeds`` times
    (seeds ``seed .. seed+random_seeds-1``) at each distance, Upward and
    Min-Overlap once at each distance, LMAP once per energy weight (its
    own distances from the scenario). Ordered scenario-major. ``scenario_text``:
    YAML overrides for every episode, applied before the method's own
    (``ScenarioOverride``)."""
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"unknown method(s) {unknown}; choose from {list(METHODS)}")
    specs = []
    for name in scenarios:
        for m in methods:
            if m in LMAP_METHODS:
                specs.append(dict(scenario=name, method=m, distance=None, seed=seed,
                                  energy_weight=LMAP_METHODS[m]))
                continue
            seeds = range(seed, seed + random_seeds) if m == "random" else [seed]
            for d in distances:
                for s in seeds:
                    specs.append(dict(scenario=name, method=m, distance=float(d), seed=s,
                                      energy_weight=None))
    for s in specs:
        s["episode_id"] = EpisodeId(s)
        s["scenario_text"] = scenario_text
    return specs


def ScenarioOverride(spec: dict) -> str:
    """``scenario_text`` YAML for a spec (planner method, distances, energy
    weight, random seed). lambda = 0 ("without energy") also disables the
    planner's ``max_energy_per_node`` cap."""
    if spec["method"] in LMAP_METHODS:
        planner = f"method: lmap, energy_weight: {float(spec['energy_weight'])!r}"
        if float(spec["energy_weight"]) == 0.0:     # "without energy": no energy cap either
            planner += ", max_energy_per_node: 0.0"
    else:
        planner = f"method: {spec['method']}, distances: [{float(spec['distance'])!r}]"
    return f"{{planner: {{{planner}}}, random_seed: {int(spec['seed'])}}}"


# Record fields that differ between two runs of the same episode: timings.
VOLATILE_KEYS = ("wall_seconds", "cpu_seconds", "simulation_wall_seconds", "mode_wall_seconds",
                 "stage_seconds", "traceback")


def Deterministic(record: dict) -> dict:
    """The record without its timings (``VOLATILE_KEYS``): what two runs of
    the same episode (any engine, any worker) must agree on."""
    return {k: v for k, v in record.items() if k not in VOLATILE_KEYS}


def LatestRecords(records: list[dict]) -> dict[str, dict]:
    """episode_id -> the last record with that id (a resumed run appends)."""
    out = {}
    for r in records:
        out[r["eval"]["episode_id"]] = r
    return out


def CompletedIds(records: list[dict]) -> set[str]:
    """Ids ``--resume`` skips: the latest record is not an ``error``."""
    return {k for k, r in LatestRecords(records).items() if r.get("status") != "error"}


# ------------------------------------------------------------ aggregation
def _valid(records):
    return [r for r in records if r.get("status") != "error" and r.get("outcome")]


def IsSafe(record: dict) -> bool:
    o = record["outcome"]
    return not (o["leaf_damage"] or o["plant_hazard"] or o["fruit_collision"])


def ScoredVisibility(record: dict) -> float:
    """Table II's visibility: the final value, or the initial one for an
    unsafe trial (the paper: "for unsafe trials, the visibility fraction is
    set to the initial value")."""
    o = record["outcome"]
    return float(o["visibility_final"] if IsSafe(record) else o["visibility_initial"])


def _mean_std(values) -> dict:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], float)
    if v.size == 0:
        return {"mean": None, "std": None, "n": 0}
    return {"mean": float(v.mean()), "std": float(v.std()), "n": int(v.size)}


def _group(records) -> dict[tuple[str, str], list[dict]]:
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in records:
        e = r["eval"]
        groups.setdefault((e["method"], DistanceLabel(e["distance"])), []).append(r)
    return groups


def _ordered(groups):
    def key(k):
        m, d = k
        mi = METHODS.index(m) if m in METHODS else len(METHODS)
        return (mi, math.inf if d == ADAPTIVE else float(d[:-2]))
    return sorted(groups, key=key)


def _nest(rows: dict[tuple[str, str], dict]) -> dict:
    out: dict = {}
    for (m, d) in _ordered(rows):
        out.setdefault(m, {})[d] = rows[(m, d)]
    return out


def Table2Row(records: list[dict]) -> dict:
    """Safety and visibility of one method row (errors are counted apart)."""
    ok = _valid(records)
    n = len(ok)

    def count(flag):
        return sum(bool(r["outcome"][flag]) for r in ok)
    safe = sum(IsSafe(r) for r in ok)
    dist = [r["chosen_action"]["distance"] * 100.0 for r in ok
            if r.get("chosen_action") and r["chosen_action"].get("distance") is not None]
    row = {"n": n, "n_errors": len(records) - n,
           "n_not_done": sum(r.get("status") != "done" for r in ok),
           "safe": safe, "safe_rate": safe / n if n else None}
    for flag in ("plant_hazard", "fruit_collision", "leaf_damage"):
        c = count(flag)
        row[flag] = c
        row[f"{flag}_rate"] = c / n if n else None
    vis = _mean_std(ScoredVisibility(r) for r in ok)
    row["visibility_mean"], row["visibility_std"] = vis["mean"], vis["std"]
    v0 = _mean_std(r["outcome"]["visibility_initial"] for r in ok)
    row["visibility_initial_mean"], row["visibility_initial_std"] = v0["mean"], v0["std"]
    row["move_distance_cm_mean"] = _mean_std(dist)["mean"]
    row["perception"] = PerceptionLabel(ok)
    row.update(MotionSummary(ok))
    return row


def MotionSummary(records: list[dict]) -> dict:
    """``motions_mean``: executed motions per episode (the action and its
    continuations; 0 when nothing moved); ``action_families``: how many
    executed motions were of each family ('pull', 'arc'). Records made
    before motions were recorded count their chosen action as one pull."""
    counts: dict[str, int] = {}
    per_episode = []
    for r in records:
        motions = r.get("motions")
        if motions is None:
            ca = r.get("chosen_action")
            motions = [dict(ca, family=ca.get("family", "pull"))] if ca else []
        per_episode.append(len(motions))
        for m in motions:
            counts[m.get("family", "pull")] = counts.get(m.get("family", "pull"), 0) + 1
    return {"motions_mean": _mean_std(per_episode)["mean"],
            "action_families": dict(sorted(counts.items()))}


def PerceptionLabel(records) -> str:
    """'segmenter / camera profile' of the records (several joined by ', ';
    records made before the field existed count as 'label / ideal')."""
    seen = sorted({f"{p.get('segmenter', '?')} / {p.get('camera', '?')}"
                   for p in (r.get("perception", {"segmenter": "label", "camera": "ideal"})
                             for r in records)})
    return ", ".join(seen) or "-"


def Table2(records: list[dict]) -> dict:
    """{method: {distance label: row}} plus ``initial_visibility`` over the
    scenarios (each scenario's mean initial visibility, then mean +- std)."""
    groups = _group(LatestRecords(records).values())
    out = _nest({k: Table2Row(v) for k, v in groups.items()})
    per_scene: dict[str, list[float]] = {}
    for r in _valid(LatestRecords(records).values()):
        per_scene.setdefault(r["eval"]["scenario"], []).append(
            r["outcome"]["visibility_initial"])
    iv = _mean_std(np.mean(v) for v in per_scene.values())
    out["initial_visibility"] = {"mean": iv["mean"], "std": iv["std"], "scenarios": iv["n"]}
    return out


def _shape_means(records, which) -> dict:
    vals = [r[which] for r in records if r.get(which)]
    row = {"n": len(vals)}
    for k in SHAPE_KEYS:
        row[k] = _mean_std(v.get(k) for v in vals)["mean"]
    return row


def Table3(records: list[dict]) -> dict:
    """{method: {"final": means, "initial": means}} of the shape metrics
    (Table III is the ``lmap`` row's ``final``)."""
    out = {}
    by_method: dict[str, list] = {}
    for r in _valid(LatestRecords(records).values()):
        by_method.setdefault(r["eval"]["method"], []).append(r)
    for m in sorted(by_method, key=lambda m: METHODS.index(m) if m in METHODS else 99):
        out[m] = {"final": _shape_means(by_method[m], "shape_final"),
                  "initial": _shape_means(by_method[m], "shape_initial")}
    return out


def Table4(records: list[dict]) -> dict:
    """{method: {stage: mean seconds or None}} with the paper's stage names,
    ``total`` (sum of the present stages, per episode),
    ``action_planning_total`` (the planner's own ``total_s``) and
    ``episode_wall`` (the whole episode including the simulation)."""
    out = {}
    by_method: dict[str, list] = {}
    for r in _valid(LatestRecords(records).values()):
        by_method.setdefault(r["eval"]["method"], []).append(r)
    for m in sorted(by_method, key=lambda m: METHODS.index(m) if m in METHODS else 99):
        rs = by_method[m]
        row, totals = {"n": len(rs)}, [0.0] * len(rs)
        for stage, keys in STAGES.items():
            vals = []
            for i, r in enumerate(rs):
                ss = r.get("stage_seconds") or {}
                v = next((ss[k] for k in keys if k in ss), None)
                if v is not None:
                    vals.append(float(v))
                    totals[i] += float(v)
            row[stage] = _mean_std(vals)["mean"]
        row["total"] = _mean_std(totals)["mean"]
        row["action_planning_total"] = _mean_std(
            (r.get("stage_seconds") or {}).get("total_s") for r in rs)["mean"]
        row["episode_wall"] = _mean_std(r.get("wall_seconds") for r in rs)["mean"]
        out[m] = row
    return out


def Table5Row(records: list[dict], threshold: float = VISIBILITY_SUCCESS) -> dict:
    """A partition of the valid episodes: ``success`` (safe and final
    visibility >= threshold), ``leaf_damage``, ``insufficient_visibility``
    (safe but below the threshold), ``other_unsafe`` (plant hazard or fruit
    collision without leaf damage)."""
    ok = _valid(records)
    row = {"n": len(ok), "n_errors": len(records) - len(ok), "success": 0, "leaf_damage": 0,
           "insufficient_visibility": 0, "other_unsafe": 0, "threshold": threshold}
    for r in ok:
        o = r["outcome"]
        if o["leaf_damage"]:
            row["leaf_damage"] += 1
        elif not IsSafe(r):
            row["other_unsafe"] += 1
        elif o["visibility_final"] < threshold:
            row["insufficient_visibility"] += 1
        else:
            row["success"] += 1
    row["success_rate"] = row["success"] / row["n"] if row["n"] else None
    row.update(MotionSummary(ok))
    return row


def Table5(records: list[dict], threshold: float = VISIBILITY_SUCCESS) -> dict:
    """{"lmap_lambda0": row, "lmap": row} for the methods present; the
    energy weight the records ran with when they agree on one (a sweep may
    set it), else the method's own."""
    latest = list(LatestRecords(records).values())
    out = {}
    for m in ("lmap_lambda0", "lmap"):
        rs = [r for r in latest if r["eval"]["method"] == m]
        if rs:
            out[m] = Table5Row(rs, threshold)
            ran = {r.get("energy_weight") for r in rs if r.get("status") != "error"}
            w = ran.pop() if len(ran) == 1 else None
            out[m]["energy_weight"] = float(w) if w is not None else LMAP_METHODS[m]
    return out


def FruitTable(records: list[dict], revealed: float = 0.9) -> dict | None:
    """Plants with several fruits (records with a ``fruits`` list), per
    method: unsafe episodes (the plant-level flags over the whole episode),
    fruits whose final visibility reaches ``revealed`` (also among those
    whose ``one_leaf_ceiling`` reaches it: one leaf moved entirely aside
    would show that much; the others are hidden by two; and by
    ``visibility_union``, seen in at least one view), the mean initial and
    final visibility and shape metrics per fruit (``shape_final_moved``:
    only the fruits with an action), wall seconds per episode by number of
    fruits. None when no record has ``fruits``."""
    multi = [r for r in _valid(records) if r.get("fruits")]
    if not multi:
        return None
    out = {}
    for (m, d), rs in _group(multi).items():
        fruits = [f for r in rs for f in r["fruits"]]
        walls: dict = {}
        for r in rs:
            walls.setdefault(str(len(r["fruits"])), []).append(r.get("wall_seconds"))
        out.setdefault(m, {})[d] = {
            "episodes": len(rs), "unsafe": sum(not IsSafe(r) for r in rs),
            "fruits": len(fruits),
            "revealed": sum(f["visibility_final"] >= revealed for f in fruits),
            "revealed_fraction": (sum(f["visibility_final"] >= revealed for f in fruits)
                                  / max(1, len(fruits))),
            # the fruits that one leaf moved entirely aside would show >= revealed
            # (the others are hidden by two leaves), and how many of them were
            "one_leaf_reachable": sum(f.get("one_leaf_ceiling", 1.0) >= revealed
                                      for f in fruits),
            "revealed_of_reachable": sum(f["visibility_final"] >= revealed
                                         and f.get("one_leaf_ceiling", 1.0) >= revealed
                                         for f in fruits),
            # seen in at least one of the episode's views (what the fused views observed)
            "revealed_union": sum(f.get("visibility_union", f["visibility_final"]) >= revealed
                                  for f in fruits),
            "visibility_union": _mean_std(f.get("visibility_union", f["visibility_final"])
                                          for f in fruits),
            # fruits revealed again by a second leaf (planner.max_reveals_per_fruit)
            "revealed_again": sum(sum(1 for x in f.get("reveals", []) if x.get("motions")) > 1
                                  for f in fruits),
            "visibility_initial": _mean_std(f["visibility_initial"] for f in fruits),
            "visibility_final": _mean_std(f["visibility_final"] for f in fruits),
            "shape_initial": {k: _mean_std((f["shape_initial"] or {}).get(k) for f in fruits)
                              for k in SHAPE_KEYS},
            "shape_final": {k: _mean_std((f["shape_final"] or {}).get(k) for f in fruits)
                            for k in SHAPE_KEYS},
            # only the fruits whose leaf was moved (the mean before the
            # unmoved targets carried their estimate's metrics)
            "shape_final_moved": {k: _mean_std((f["shape_final"] or {}).get(k)
                                               for f in fruits if f.get("action"))
                                  for k in SHAPE_KEYS},
            "wall_seconds_by_fruits": {k: _mean_std(v) for k, v in sorted(walls.items())},
            # targets whose plan moved a leaf: was it a true occluder of
            # the fruit (render labels; None when it could not be told)
            "moves": sum(bool(t.get("motions")) for r in rs for t in r.get("targets", [])),
            "moves_of_true_occluder": sum(bool(t.get("motions")) and t.get("leaf_is_occluder")
                                          is True for r in rs for t in r.get("targets", [])),
            "no_feasible_action_targets": sum(
                str(t.get("outcome", "")).startswith("no_feasible_action")
                for r in rs for t in r.get("targets", [])),
            "phantom_targets": sum(r.get("phantom_targets", 0) or 0 for r in rs),
            "revealed_threshold": revealed}
    return out


def AllTables(records: list[dict], threshold: float = VISIBILITY_SUCCESS) -> dict:
    out = {"table2": Table2(records), "table3": Table3(records),
           "table4": Table4(records), "table5": Table5(records, threshold)}
    fruits = FruitTable(records)
    if fruits is not None:
        out["fruits"] = fruits
    return out


# ------------------------------------------------------------ record files
def _Line(raw: bytes) -> dict | None:
    """A complete record of an ``episodes.jsonl`` line (strict UTF-8 JSON
    map with ``eval.episode_id``), else None."""
    try:
        rec = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError):
        return None
    ok = isinstance(rec, dict) and isinstance(rec.get("eval"), dict) \
        and "episode_id" in rec["eval"]
    return rec if ok else None


def RepairLog(path: Path) -> int:
    """Sets aside the lines of an ``episodes.jsonl`` that are not complete
    JSON records (a torn last line of a killed run, a record glued onto
    one, bytes that are not UTF-8): they are appended to ``<name>.torn``
    byte for byte (nothing replaced) and the log is rewritten (atomically)
    with the good lines, unchanged, each ending in a newline, so their
    episodes are re-run and nothing is appended to a torn line. Returns how
    many lines were set aside."""
    import os
    path = Path(path)
    if not path.exists():
        return 0
    data = path.read_bytes()
    good, bad = [], []
    for line in data.splitlines():
        if not line.strip():
            continue
        (good if _Line(line) is not None else bad).append(line)
    if not bad and (not data or data.endswith(b"\n")):
        return 0
    if bad:
        with open(path.with_name(path.name + ".torn"), "ab") as f:
            f.write(b"".join(line + b"\n" for line in bad))
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(b"".join(line + b"\n" for line in good))
    os.replace(tmp, path)
    return len(bad)


def ReadRecords(path: Path) -> list[dict]:
    """Records of an ``episodes.jsonl`` (missing file: none; a torn line
    from an interrupted run, JSON or UTF-8, is skipped here; ``RepairLog``
    sets such lines aside before a resumed run appends)."""
    path = Path(path)
    if not path.exists():
        return []
    out = []
    for line in path.read_bytes().splitlines():
        if not line.strip():
            continue
        try:
            out.append(json.loads(line.decode("utf-8")))
        except (UnicodeDecodeError, json.JSONDecodeError):
            continue
    return out
