"""Calibrates the planner's ``max_energy_per_node`` (predicted ARAP energy
per deformable leaf node above which an action is rejected as a damage
risk) from simulated episodes.

    python scripts/calibrate_energy_cap.py --out cap.json out/eval_chain/episodes.jsonl [...]

Input: episode records written by ``lmap-drake eval`` (``episodes.jsonl``)
or ``lmap-drake run`` (``episode.json``) whose chosen action carries the
predicted ``energy_per_node`` (the LMAP rows, any energy weight; run them
with the cap off, ``{planner: {max_energy_per_node: 0.0}}``, or the data
only shows actions below the current cap). Each record is labelled
unsafe when the FEM plant world flagged leaf damage or a plant hazard
(strain / petiole force thresholds of ``plant_scene.outcome``).

Output: the cap halfway between the highest safe energy below the lowest
unsafe energy and that lowest unsafe energy (so every unsafe record lies
above it), how many records it separates correctly, and the sorted
(energy, safe, petiole force, strain) rows, as JSON.

The default ``PlannerConfig.max_energy_per_node`` = 5.9e-7 m^2 came from
this script on 57 records (27 unsafe; 53 separated, 4 safe ones above the
cap): the suite's LMAP lambda 1 and 0 episodes of two evaluations (before and
after free space along background rays), nine lambda-0 runs on the three
small-leaf heavy scenes with caps 8e-7 / 1e-6 / 1.3e-6, and the earlier
cap-off episodes. It replaced 7.0e-7 (48 episodes) when a suite episode was a
hazard at 6.0e-7 (small leaf, petiole 15.3 N). Validate a new value on
scenes that were not used to fit it (``lmap-drake eval --scenarios 12 --seed
S``). The total energy does
not separate small from large leaves (a small leaf is hazardous at an
energy a large one bears); per node it does.
"""
from __future__ import annotations

import json
from pathlib import Path


def LoadRecords(paths: list[str]) -> list[dict]:
    out = []
    for p in paths:
        text = Path(p).read_text()
        if p.endswith(".jsonl"):
            out += [json.loads(line) for line in text.splitlines() if line.strip()]
        else:
            out.append(json.loads(text))
    return out


def Calibrate(records: list[dict]) -> dict:
    """The cap and its separation on records with an energy and an outcome."""
    rows = []
    for r in records:
        a, o = r.get("chosen_action") or {}, r.get("outcome") or {}
        if a.get("energy_per_node") is None or not o:
            continue
        rows.append(dict(scenario=r.get("scenario"), energy=float(a["energy_per_node"]),
                         safe=not (o.get("leaf_damage") or o.get("plant_hazard")),
                         petiole_force_n=o.get("max_petiole_force"),
                         strain_p95=o.get("max_strain_percentile")))
    if not rows:
        raise ValueError("no record has both a chosen action energy_per_node and an outcome")
    rows.sort(key=lambda r: r["energy"])
    unsafe = [r["energy"] for r in rows if not r["safe"]]
    if not unsafe:
        cap = rows[-1]["energy"]
        note = "no unsafe record: the cap is the highest energy seen (no evidence above it)"
    else:
        lo = min(unsafe)
        safe_below = [r["energy"] for r in rows if r["safe"] and r["energy"] < lo]
        cap = 0.5 * (max(safe_below) + lo) if safe_below else 0.5 * lo
        note = "halfway between the highest safe energy below the lowest unsafe one and it"
    correct = sum((r["energy"] <= cap) == r["safe"] for r in rows)
    return dict(max_energy_per_node=cap, note=note, num_records=len(rows),
                num_unsafe=len(unsafe), correctly_separated=correct,
                safe_above_cap=sum(r["safe"] and r["energy"] > cap for r in rows),
                rows=rows)
