"""Writing the eval tables (``tables.AllTables``): Markdown, the JSON
files and matplotlib bar charts."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from lmap_drake.evaluation.tables import (ADAPTIVE, SHAPE_KEYS, STAGES, VISIBILITY_SUCCESS,
                                          AllTables)
from lmap_drake.viz import PNG_COMPRESS_LEVEL


def MotionFamilies(r: dict) -> str:
    """A table row's motion families and their counts, e.g. 'arc 2, pull 1'."""
    fam = r.get("action_families") or {}
    return ", ".join(f"{k} {v}" for k, v in fam.items()) or "-"


def _f(x, fmt="{:.2f}"):
    return "-" if x is None else fmt.format(x)


def Markdown(tables: dict, title: str = "lmap-drake eval", notes: str = "") -> str:
    """Tables II-V (``AllTables``) as one Markdown document."""
    t2, t3, t4, t5 = (tables[k] for k in ("table2", "table3", "table4", "table5"))
    L = [f"# {title}", ""]
    if notes:
        L += [notes, ""]
    L += ["## Table II analogue: action planning (safety, visibility)", "",
          "| Method | Move distance | Safe | Plant hazard | Fruit collision | Leaf damage "
          "| Visibility fraction | Initial visibility | Errors | Motions / episode "
          "| Motion families | Perception (segmenter / camera) |",
          "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for m, rows in t2.items():
        if m == "initial_visibility":
            continue
        for d, r in rows.items():
            dist = (f"{_f(r['move_distance_cm_mean'], '{:.1f}')} cm (adaptive)"
                    if d == ADAPTIVE else d.replace("cm", " cm"))
            n = r["n"]
            L.append(f"| {m} | {dist} | {r['safe']} / {n} | {r['plant_hazard']} / {n} | "
                     f"{r['fruit_collision']} / {n} | {r['leaf_damage']} / {n} | "
                     f"{_f(r['visibility_mean'])} ± {_f(r['visibility_std'])} | "
                     f"{_f(r['visibility_initial_mean'])} ± "
                     f"{_f(r['visibility_initial_std'])} | {r['n_errors']} | "
                     f"{_f(r.get('motions_mean'))} | {MotionFamilies(r)} | "
                     f"{r.get('perception', '-')} |")
    iv = t2.get("initial_visibility", {})
    L += ["", f"Initial visibility over {iv.get('scenarios', 0)} scenario(s): "
          f"{_f(iv.get('mean'))} ± {_f(iv.get('std'))}. Unsafe trials count their initial "
          "visibility (as in the paper); std is the population std.", ""]
    L += ["## Table III analogue: shape completion after the action", "",
          "| Method | Estimate | n | Chamfer (cm) | Volume err (cm³) | Center err (cm) "
          "| Angle err (deg) |", "|---|---|---|---|---|---|---|"]
    for m, r in t3.items():
        for which in ("final", "initial"):
            s = r[which]
            L.append(f"| {m} | {which} | {s['n']} | " + " | ".join(
                _f(s[k]) for k in SHAPE_KEYS) + " |")
    L += ["", "## Table IV analogue: runtime per stage (mean s)", "",
          "| Method | n | " + " | ".join(k.replace("_", " ") for k in STAGES) +
          " | total | action planning total | episode wall |",
          "|---" * (len(STAGES) + 5) + "|"]
    for m, r in t4.items():
        L.append(f"| {m} | {r['n']} | " + " | ".join(_f(r[k]) for k in STAGES) +
                 f" | {_f(r['total'])} | {_f(r['action_planning_total'])} | "
                 f"{_f(r['episode_wall'], '{:.1f}')} |")
    L += ["", "`-`: stage not recorded (branch completion is timed inside fruit "
          "completion unless `stage_seconds` carries it).", ""]
    thr = next(iter(t5.values()), {}).get("threshold", VISIBILITY_SUCCESS)
    L += ["## Table V analogue: energy weight", "",
          "| Method | λ | Success | Leaf damage | Insufficient visibility "
          f"(< {thr:g}) | Other unsafe | Errors | Motions / episode | Motion families |",
          "|---|---|---|---|---|---|---|---|---|"]
    for m, r in t5.items():
        L.append(f"| {m} | {r['energy_weight']:g} | {r['success']} / {r['n']} | "
                 f"{r['leaf_damage']} | {r['insufficient_visibility']} | "
                 f"{r['other_unsafe']} | {r['n_errors']} | {_f(r.get('motions_mean'))} | "
                 f"{MotionFamilies(r)} |")
    return "\n".join(L) + "\n"


def SaveFigure(fig, path: Path) -> str:
    """Writes and closes a matplotlib figure; returns the file name."""
    import matplotlib.pyplot as plt
    fig.tight_layout()
    fig.savefig(path, dpi=110, pil_kwargs={"compress_level": PNG_COMPRESS_LEVEL})
    plt.close(fig)
    return path.name


def SavePlots(tables: dict, out: Path) -> list[str]:
    """Bar charts of the four tables; returns the file names written."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out = Path(out)
    files = []
    t2 = tables["table2"]
    rows = [(m, d, r) for m, rs in t2.items() if m != "initial_visibility"
            for d, r in rs.items()]
    if rows:
        labels = [f"{m}\n{d}" for m, d, _ in rows]
        x = np.arange(len(rows))
        fig, axes = plt.subplots(1, 2, figsize=(max(8, 1.2 * len(rows) + 4), 4))
        w = 0.27
        for i, (k, name) in enumerate([("safe_rate", "safe"),
                                       ("plant_hazard_rate", "plant hazard"),
                                       ("fruit_collision_rate", "fruit collision")]):
            axes[0].bar(x + (i - 1) * w, [r[k] or 0 for _, _, r in rows], w, label=name)
        axes[0].set_xticks(x, labels, fontsize=7)
        axes[0].set_ylim(0, 1.05)
        axes[0].set_title("Table II: rates")
        axes[0].legend(fontsize=7)
        axes[1].bar(x, [r["visibility_mean"] or 0 for _, _, r in rows],
                    yerr=[r["visibility_std"] or 0 for _, _, r in rows], capsize=3,
                    label="scored visibility")
        axes[1].scatter(x, [r["visibility_initial_mean"] or 0 for _, _, r in rows],
                        color="k", marker="_", s=300, label="initial", zorder=3)
        axes[1].set_xticks(x, labels, fontsize=7)
        axes[1].set_ylim(0, 1.1)
        axes[1].set_title("Table II: visibility fraction")
        axes[1].legend(fontsize=7)
        files.append(SaveFigure(fig, out / "table2.png"))
    t3 = tables["table3"]
    if t3:
        fig, axes = plt.subplots(1, 4, figsize=(13, 3.4))
        ms = list(t3)
        x = np.arange(len(ms))
        for ax, k in zip(axes, SHAPE_KEYS):
            ax.bar(x - 0.2, [t3[m]["initial"][k] or 0 for m in ms], 0.4, label="initial")
            ax.bar(x + 0.2, [t3[m]["final"][k] or 0 for m in ms], 0.4, label="final")
            ax.set_xticks(x, ms, fontsize=7, rotation=20)
            ax.set_title(k)
        axes[0].legend(fontsize=7)
        fig.suptitle("Table III: shape metrics before / after the action")
        files.append(SaveFigure(fig, out / "table3.png"))
    t4 = tables["table4"]
    if t4:
        fig, ax = plt.subplots(figsize=(9, 3.8))
        ms = list(t4)
        x = np.arange(len(STAGES))
        w = 0.8 / len(ms)
        for i, m in enumerate(ms):
            ax.bar(x + (i - (len(ms) - 1) / 2) * w, [t4[m][k] or 0 for k in STAGES], w, label=m)
        ax.set_xticks(x, [k.replace("_", "\n") for k in STAGES], fontsize=7)
        ax.set_ylabel("mean seconds")
        ax.set_title("Table IV: runtime per stage")
        ax.legend(fontsize=7)
        files.append(SaveFigure(fig, out / "table4.png"))
    t5 = tables["table5"]
    if t5:
        fig, ax = plt.subplots(figsize=(5, 3.5))
        ms = list(t5)
        bottom = np.zeros(len(ms))
        for k in ("success", "leaf_damage", "insufficient_visibility", "other_unsafe"):
            v = np.array([t5[m][k] for m in ms], float)
            ax.bar([f"{m}\n(λ={t5[m]['energy_weight']:g})" for m in ms], v, bottom=bottom,
                   label=k.replace("_", " "))
            bottom += v
        ax.set_ylabel("episodes")
        ax.set_title("Table V: energy weight")
        ax.legend(fontsize=7)
        files.append(SaveFigure(fig, out / "table5.png"))
    return files


def WriteTables(records: list[dict], out: Path, threshold: float = VISIBILITY_SUCCESS,
                notes: str = "", plots: bool = True) -> list[str]:
    """table2..5.json, tables.md and the PNGs in ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    tables = AllTables(records, threshold)
    files = []
    for k, v in tables.items():
        (out / f"{k}.json").write_text(json.dumps(v, indent=2))
        files.append(f"{k}.json")
    text = Markdown(tables, notes=notes)
    if "fruits" in tables:
        text += FruitMarkdown(tables["fruits"])
    (out / "tables.md").write_text(text)
    files.append("tables.md")
    if plots:
        files += SavePlots(tables, out)
    return files


def FruitMarkdown(t: dict) -> str:
    """The per-fruit table (``tables.FruitTable``) as a Markdown section."""
    L = ["", "## Plants with several fruits (per fruit)", "",
         "| Method | Move distance | Episodes | Unsafe | Fruits | Revealed (final vis >= "
         "0.9) | Revealed of those one leaf can reveal | Seen >= 0.9 over all views | "
         "Revealed again by another leaf | "
         "Visibility initial → final | Chamfer initial → final (cm; moved: the fruits whose "
         "leaf was moved) | Wall s / episode "
         "(by fruits) |",
         "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for m, rows in t.items():
        for d, r in rows.items():
            walls = ", ".join(f"{k}: {_f(v['mean'], '{:.0f}')}"
                              for k, v in r["wall_seconds_by_fruits"].items())
            L.append(f"| {m} | {d} | {r['episodes']} | {r['unsafe']} | {r['fruits']} | "
                     f"{r['revealed']} ({_f(r['revealed_fraction'])}) | "
                     f"{r.get('revealed_of_reachable', '-')} of "
                     f"{r.get('one_leaf_reachable', '-')} | "
                     f"{r.get('revealed_union', '-')} | "
                     f"{r.get('revealed_again', '-')} | "
                     f"{_f(r['visibility_initial']['mean'])} → "
                     f"{_f(r['visibility_final']['mean'])} | "
                     f"{_f(r['shape_initial']['chamfer_cm']['mean'])} → "
                     f"{_f(r['shape_final']['chamfer_cm']['mean'])} (moved: "
                     f"{_f(r['shape_final_moved']['chamfer_cm']['mean'])}) "
                     f"| {walls} |")
    return "\n".join(L) + "\n"
