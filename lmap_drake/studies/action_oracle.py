"""How much of the fruit can one safe pull reveal in the FEM plant world?
Executes the LMAP planner's best-looking candidates, not only its choice.

    python scripts/action_oracle.py --out out/oracle.json
    python scripts/action_oracle.py --out o.json --top 6 \
        --scenario_names small_leaf_thin_branch_round_red_heavy

Per scenario of ``--scenario_file`` (default: diagrams/suite.yaml):

1. The LMAP episode (``RunEpisode``, lambda = ``--energy_weight``) gives the
   planner's choice, its outcome, and the candidate table.
2. Candidates that passed the IK and robot checks (and so have a predicted
   deformation) are ranked by predicted visibility (the planner's voxel
   model of the estimated fruit), whatever the energy cap, leaf-fruit and
   early-stop verdicts; the ``--top`` best that are not the choice are each
   executed in their own episode with ``planner.force_action`` (same
   observation, same plan, only the executed action differs).
3. Every executed action is scored by the plant world (ground truth):
   visibility of the true fruit, plant hazard (petiole force), leaf damage
   (strain), fruit collision.

Per scenario the JSON holds the rows (predicted visibility, predicted
energy per node, the planner's verdict, the measured outcome) and a summary:
the LMAP choice's visibility, the best visibility among the executed actions
that were safe, and whether any safe executed action reached 0.95. The
records are ``lmap-drake eval`` episode records (``episodes.jsonl`` next to
the JSON), so ``scripts/calibrate_energy_cap.py`` can read them too.

It is a bound from below on what one pull can do (only ``--top`` actions per
scene are executed), and a check of the planner's ranking, not a method: it
needs the ground truth.
"""
from __future__ import annotations

import concurrent.futures as cf
import json
import multiprocessing as mp
import time
import traceback
from pathlib import Path

from lmap_drake.episode import RunSimEpisode
from lmap_drake.evaluation.engines import InitWorker
from lmap_drake.evaluation.run_eval import JsonDefault
from lmap_drake.evaluation.tables import IsSafe
from lmap_drake.paths import REPO_ROOT
from lmap_drake.scenario import LoadScenario
from lmap_drake.studies.shape_benchmark import SuiteScenarioNames

SUITE = REPO_ROOT / "diagrams" / "suite.yaml"


def RunOne(suite: str, name: str, text: str, with_candidates: bool) -> dict:
    """One episode in this (worker) process; never raises."""
    t0 = time.perf_counter()
    try:
        s = LoadScenario(filename=suite, scenario_name=name, scenario_text=text)
        res = RunSimEpisode(s)
        rec = dict(res.record)
        plan = res.status.plan
        if with_candidates and plan is not None:
            rec["candidates"] = [dict(c.Row(), predicted=c.deformed_leaf_W is not None)
                                 for c in plan.candidates]
            rec["seen_max"] = plan.seen_max
    except BaseException as err:  # noqa: BLE001 - recorded, not raised
        if isinstance(err, KeyboardInterrupt):
            raise
        rec = {"status": "error", "message": f"{type(err).__name__}: {err}",
               "traceback": traceback.format_exc(), "wall_seconds": time.perf_counter() - t0}
    rec["eval"] = {"scenario": name, "scenario_text": text, "suite_file": suite}
    return rec


def ActionKey(row: dict) -> tuple:
    return (int(row["grasp_id"]), int(row["direction_id"]), round(float(row["distance"]), 4))


def Outcome(rec: dict) -> dict:
    o = rec.get("outcome") or {}
    safe = bool(o) and IsSafe(rec)
    return {"status": rec.get("status"), "message": rec.get("message", "")[:300],
            "visibility_initial": o.get("visibility_initial"),
            "visibility_final": o.get("visibility_final"),
            "max_petiole_force": o.get("max_petiole_force"),
            "max_strain_percentile": o.get("max_strain_percentile"),
            "plant_hazard": o.get("plant_hazard"), "leaf_damage": o.get("leaf_damage"),
            "fruit_collision": o.get("fruit_collision"), "safe": safe}


def Ranked(candidates: list[dict], seen_max: int, chosen: tuple | None, top: int) -> list[dict]:
    """The ``top`` predicted candidates (robot checks passed) with the highest
    predicted visibility, the choice excluded; ties go to lower energy."""
    rows = [c for c in candidates if c.get("predicted") and c.get("seen", -1) >= 0
            and ActionKey(c) != chosen]
    rows.sort(key=lambda c: (-c["seen"], c.get("energy_per_node") or 0.0))
    return [dict(c, predicted_visibility=c["seen"] / max(seen_max, 1)) for c in rows[:top]]


def Summary(rows: list[dict], threshold: float = 0.95) -> dict:
    """Best safe measured visibility over the executed rows."""
    safe = [r for r in rows if r["outcome"]["safe"]]
    best = max(safe, key=lambda r: r["outcome"]["visibility_final"], default=None)
    lmap = next((r for r in rows if r["lmap_choice"]), None)
    return {
        "visibility_initial": rows[0]["outcome"]["visibility_initial"] if rows else None,
        "lmap_visibility": lmap["outcome"]["visibility_final"] if lmap else None,
        "lmap_safe": lmap["outcome"]["safe"] if lmap else None,
        "executed": len(rows), "safe": len(safe),
        "best_safe_visibility": best["outcome"]["visibility_final"] if best else None,
        "best_safe_action": best["action"] if best else None,
        "best_safe_petiole_force": best["outcome"]["max_petiole_force"] if best else None,
        "safe_reaching_threshold": sum(r["outcome"]["visibility_final"] >= threshold
                                       for r in safe),
    }


def RunOracle(out: str, scenario_file: str = str(SUITE), scenario_names: str = "", top: int = 6,
              energy_weight: float = 1.0, workers: int = 2) -> int:
    """Runs the oracle (see the module docstring) on ``scenario_file``'s
    scenes (``scenario_names``: comma-separated, default all) and writes
    ``out`` and ``out``'s ``.episodes.jsonl``; returns the exit code."""
    config = dict(out=out, scenario_file=scenario_file, scenario_names=scenario_names, top=top,
                  energy_weight=energy_weight, workers=workers)
    suite = str(Path(scenario_file).resolve())
    names = [n for n in scenario_names.split(",") if n] or SuiteScenarioNames(suite)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    log = out.with_suffix(".episodes.jsonl")
    base = f"{{planner: {{method: lmap, energy_weight: {energy_weight!r}}}}}"
    t_start = time.perf_counter()
    result = {"config": config, "scenarios": {}}
    with cf.ProcessPoolExecutor(max_workers=max(1, workers),
                                mp_context=mp.get_context("spawn"),
                                initializer=InitWorker, initargs=(1,)) as pool, \
            open(log, "w") as f:
        def record(rec):
            f.write(json.dumps({k: v for k, v in rec.items() if k != "candidates"},
                               default=JsonDefault) + "\n")
            f.flush()
        print(f"[oracle] {len(names)} scene(s): the LMAP episodes", flush=True)
        firsts = {n: pool.submit(RunOne, suite, n, base, True) for n in names}
        forced = {}
        for n in names:
            rec = firsts[n].result()
            record(rec)
            ch = rec.get("chosen_action")
            entry = {"rows": [], "message": rec.get("message", "")}
            result["scenarios"][n] = entry
            if ch is not None:
                entry["rows"].append({
                    "action": list(ActionKey(ch)), "lmap_choice": True,
                    "predicted_visibility": (rec.get("predicted_visibility") or {}).get("chosen"),
                    "energy_per_node": ch.get("energy_per_node"), "planner_reason": "",
                    "outcome": Outcome(rec)})
            cands = Ranked(rec.get("candidates", []), rec.get("seen_max") or 0,
                           ActionKey(ch) if ch else None, top)
            print(f"[oracle] {n}: LMAP {rec.get('status')} vis "
                  f"{Outcome(rec)['visibility_final']}; executing {len(cands)} more",
                  flush=True)
            for c in cands:
                text = (f"{{planner: {{method: lmap, energy_weight: {energy_weight!r}, "
                        f"force_action: [{c['grasp_id']}, {c['direction_id']}, "
                        f"{float(c['distance'])!r}]}}}}")
                forced[pool.submit(RunOne, suite, n, text, False)] = (n, c)
        for k, fut in enumerate(cf.as_completed(forced), 1):
            n, c = forced[fut]
            rec = fut.result()
            record(rec)
            o = Outcome(rec)
            same = rec.get("chosen_action") is not None and \
                ActionKey(rec["chosen_action"]) == ActionKey(c)
            pv = (rec.get("predicted_visibility") or {}).get("chosen")
            result["scenarios"][n]["rows"].append({
                "action": list(ActionKey(c)), "lmap_choice": False,
                "predicted_visibility": c["predicted_visibility"],
                # the forced episode re-plans: its prediction should match
                "replanned_predicted_visibility": pv, "executed_as_planned": same,
                "energy_per_node": c.get("energy_per_node"),
                "planner_reason": c.get("reason", ""), "outcome": o})
            print(f"[oracle] [{k}/{len(forced)}] {n} {list(ActionKey(c))}: predicted "
                  f"{c['predicted_visibility']:.2f}, measured {o['visibility_final']}, "
                  f"petiole {o['max_petiole_force']}, safe {o['safe']}", flush=True)
    for n, e in result["scenarios"].items():
        e["summary"] = Summary([r for r in e["rows"] if r["outcome"]["status"] != "error"
                                and r["outcome"]["visibility_final"] is not None])
    sums = [e["summary"] for e in result["scenarios"].values()]
    # As in Table II: a scene without a safe action keeps its initial visibility.
    best = [s["best_safe_visibility"] if s["best_safe_visibility"] is not None
            else (s["visibility_initial"] or 0.0) for s in sums]
    lm = [s["lmap_visibility"] if s["lmap_safe"] else (s["visibility_initial"] or 0.0)
          for s in sums]
    result["overall"] = {
        "scenes": len(sums),
        "lmap_mean_visibility": sum(lm) / max(len(lm), 1),
        "best_safe_mean_visibility": sum(best) / max(len(best), 1),
        "scenes_with_a_safe_action_reaching_0.95": sum(s["safe_reaching_threshold"] > 0
                                                       for s in sums),
        "wall_seconds": time.perf_counter() - t_start}
    out.write_text(json.dumps(result, indent=2, default=JsonDefault))
    print(json.dumps(result["overall"], indent=2))
    print(f"[oracle] wrote {out} and {log}")
    return 0
