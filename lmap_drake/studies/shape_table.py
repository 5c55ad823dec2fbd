"""The analogue of paper Table I: shape completion with initial occlusion
and without occlusion (leaf removed) for SupEps, HoMa-style and SSC.

Cases come from the 12-scenario plant suite when ``diagrams/suite.yaml``
exists (``--source auto``, the default, or ``--source suite``), otherwise
from the synthetic benchmark of ``lmap_drake.studies.shape_benchmark`` (12 seeded
peppers of the project's family beside a branch, a leaf-like plate hiding
35-75 % of the fruit, exact labels). The JSON and the Markdown say which.

  .venv/bin/python scripts/eval_shape.py --out out/eval_shape.json

Writes FILE.json ({"source", "ssc": {"initial_occlusion": {"chamfer_cm",
"volume_err_cm3", "center_err_cm", "angle_err_deg", "seconds"},
"without_occlusion": {...}}, ..., "rows": [...]}) and FILE.md (table).
``seconds`` is the fruit-completion time per fruit (free space + fit +
hypothesis set; branch completion reported separately as
``branch_seconds``). With hypothesis sets (``shape.ssc.num_hypotheses`` >
0; SSC and HoMa-style) every method and condition also has
``volume_interval_coverage`` (the fraction of cases whose true volume lies
in the set's 90 % volume interval), ``volume_interval_width`` (the mean
interval width over the true volume) and ``hypotheses_seconds``; rows
hold ``volume_interval_cm3``, ``volume_in_interval``,
``volume_interval_rel_width`` and ``num_hypotheses`` (kept).

``--seeds 0,1,2,3`` repeats every fit with those optimiser seeds (surface /
negative subsampling): the tables are then means over cases and seeds, and
``"seed_std"`` holds, per method and condition, the standard deviation over
seeds of the per-seed means (the run-to-run noise a difference between two
methods has to exceed). Rows of the DeepSDF methods also record how many
iterations had an active negative loss (``neg_iters``) and an active
peduncle loss (``ped_iters``), and how many negative points the estimate
still has inside it (``neg_inside``: leaf, observed branch, free space,
more than 0.5 mm deep). Every row splits the centre error along the view
ray to the true centre (``center_depth_cm``, + = too far), the vertical
across it (``center_up_cm``, + = too high) and the rest
(``center_side_cm``); the means give their root mean squares
(``center_depth_rms_cm`` ...).

``--fruit_mesh_dir DIR`` evaluates pepper meshes from files instead of the
suite's procedural peppers: every ``DIR/NAME.{obj,ply,stl}`` (with
``DIR/NAME.peduncle.{obj,ply,stl}`` as its stalk when present; metres, +z =
peduncle axis, see ``lmap_drake/plants/fruit_mesh.py``) is put in each suite
scene (``--num_cases`` / ``--scenario_names``) as
``plant_scene.fruit.mesh_file``, with the scene's pose and occlusion. The
tables are then means over fruits and scenes; ``"per_fruit"`` holds the same
layout per fruit (``d["per_fruit"][NAME][method][condition][metric]``),
``"fruits"`` each file's volume and extents, and ``"skipped"`` the scenes a
fruit could not be placed in (e.g. a leaf too small to hide a large fruit as
much as asked), with the reason. A mesh that fails the checks stops the run
before anything is evaluated (exit code 2, the file named).

  .venv/bin/python scripts/make_test_peppers.py --out out/test_peppers --count 6
  .venv/bin/python scripts/eval_shape.py --fruit_mesh_dir out/test_peppers --out out/shape_files.json

``OUT_figures/`` (beside ``--out``) gets a picture of the first ``--figures``
(1) cases of each fruit per condition (``ShapeCaseFigure``: the camera's and
a side view of the truth and each method's estimate). The JSON, the
Markdown and the pictures are written at the end (an interrupted run leaves
only ``OUT_figures.partial/``).
"""
from __future__ import annotations

import dataclasses as dc
import json
import shutil
import time
from pathlib import Path

import numpy as np
import torch
from pydrake.common.yaml import yaml_load_typed

from lmap_drake.errors import InputError
from lmap_drake.evaluation.figures import ShapeCaseFigure, ShapeViewAxes
from lmap_drake.evaluation.progress import Progress
from lmap_drake.paths import REPO_ROOT
from lmap_drake.plants.fruit_mesh import FruitMeshFolder, LoadFruitMesh
from lmap_drake.plants.generator import PlantGenerationError
from lmap_drake.scenario import MigrateScenarioText
from lmap_drake.shape.config import ShapeConfig
from lmap_drake.studies import shape_benchmark as benchmark
from lmap_drake.shape.completion import CompleteScene
from lmap_drake.shape.deepsdf import LoadDecoder
from lmap_drake.shape.free_space import FreeSpacePoints
from lmap_drake.shape.metrics import MeshCentroid, MeshVolume, ShapeMetrics

METRICS = ("chamfer_cm", "volume_err_cm3", "center_err_cm", "angle_err_deg", "seconds")
CONDITIONS = ("initial_occlusion", "without_occlusion")
NAMES = {"supeps": "SupEps", "homa": "HoMa (DeepSDF, no scene)", "ssc": "SSC"}


@dc.dataclass
class ShapeTableOptions:
    """The table's settings (the flags of ``scripts/eval_shape.py``)."""
    out: str = ""                    # JSON file
    md: str | None = None            # Markdown file (None: ``out`` with .md)
    methods: str = "supeps,homa,ssc"
    num_cases: int = 12
    source: str = "auto"             # auto, synthetic or suite
    threads: int = 1                 # torch threads
    iterations: int | None = None    # SSC iterations (None: the shape config's)
    seeds: str = "0"                 # optimiser seeds, comma-separated
    shape_text: str = "{}"           # YAML overrides of ShapeConfig
    fruit_mesh_dir: str | None = None   # pepper meshes from files instead of the suite's
    conditions: str = ",".join(CONDITIONS)
    scenario_names: str | None = None   # comma-separated suite scenes
    figures: int = 1                 # pictures of the first N cases of each fruit


def Cases(source: str, num: int, fruit_files: dict | None = None, names=None):
    """(source, case name, fruit name, make(occluded) -> ShapeCase)."""
    suite = REPO_ROOT / benchmark.SUITE_FILE
    if fruit_files is not None:
        if not suite.is_file():
            raise InputError(f"--fruit_mesh_dir needs the suite {suite} (make it with "
                             f"scripts/make_suite.py)")
        names = names or benchmark.SuiteScenarioNames(suite)[:num]
        for fruit, (f, ped) in fruit_files.items():
            text = ("{plant_scene: {fruit: {mesh_file: " + json.dumps(str(f.resolve())) +
                    ", peduncle_file: " + json.dumps(str(Path(ped).resolve()) if ped else "")
                    + "}}}")
            for n in names:
                yield "suite+files", f"{fruit}@{n}", fruit, \
                    lambda occ, n=n, text=text, c=f"{fruit}@{n}": benchmark.MakeSuiteCase(
                        suite, n, occ, scenario_text=text, case_name=c)
    elif source == "suite" or (source == "auto" and suite.is_file()):
        names = names or benchmark.SuiteScenarioNames(suite)[:num]
        for n in names:
            yield "suite", n, "", lambda occ, n=n: benchmark.MakeSuiteCase(suite, n, occ)
    else:
        for i in range(num):
            yield "synthetic", f"synthetic_{i:02d}", "", \
                lambda occ, i=i: benchmark.MakeSyntheticCase(i, occ)


def CentreOffsetCm(est, case, sem) -> dict:
    """The estimated centre minus the true one (cm), split along the view
    ray from the camera to the true centre (``center_depth_cm``, + = too
    far), the world vertical across it (``center_up_cm``, + = too high)
    and the rest (``center_side_cm``, unsigned)."""
    c_true = MeshCentroid(case.gt_vertices_W, case.gt_faces)
    off = (MeshCentroid(est.vertices_W, est.faces) - c_true) * 100.0
    ray, up, _ = ShapeViewAxes(sem.X_WC, c_true)
    depth, height = float(off @ ray), float(off @ up)
    side = float(np.linalg.norm(off - depth * ray - height * up))
    return dict(center_depth_cm=depth, center_up_cm=height, center_side_cm=side)


def Means(rows, methods) -> dict:
    """``{method: {condition: {metric: mean}}}`` over ``rows``."""
    out = {}
    for m in methods:
        out[m] = {}
        for cond in CONDITIONS:
            sel = [r for r in rows if r["method"] == m and r["condition"] == cond]
            out[m][cond] = {k: float(np.mean([r[k] for r in sel])) if sel else float("nan")
                            for k in METRICS}
            out[m][cond]["num_cases"] = len({r["case"] for r in sel})
            iv = [r for r in sel if "volume_in_interval" in r]
            if iv:     # the hypothesis sets' volume intervals (shape.ssc.num_hypotheses)
                out[m][cond]["volume_interval_coverage"] = float(
                    np.mean([r["volume_in_interval"] for r in iv]))
                out[m][cond]["volume_interval_width"] = float(
                    np.mean([r["volume_interval_rel_width"] for r in iv]))
                out[m][cond]["hypotheses_seconds"] = float(
                    np.mean([r["hypotheses_seconds"] for r in iv]))
            for k in ("center_depth_cm", "center_up_cm", "center_side_cm"):
                vals = [r[k] for r in sel if k in r]
                out[m][cond][k.replace("_cm", "_rms_cm")] = (
                    float(np.sqrt(np.mean(np.square(vals)))) if vals else float("nan"))
    return out


def SceneNegatives(sem, voxel: float) -> np.ndarray:
    """The observed negatives of SSC (leaf, branch, free space; W, m)."""
    cam = np.asarray(sem.X_WC, float)[:3, 3]
    obs = [p for p in (sem.fruit_points_W, sem.leaf_points_W, sem.branch_points_W,
                       sem.background_points_W) if len(p)]
    free = FreeSpacePoints(cam, np.vstack(obs), sem.fruit_points_W, voxel)
    return np.vstack([np.asarray(p, float).reshape(-1, 3) for p in
                      (sem.leaf_points_W, sem.branch_points_W, free)])


def Markdown(res: dict, methods) -> str:
    seeds = res.get("seeds", [0])
    # only the conditions evaluated (--conditions), not rows of nan
    conds = [c for c in CONDITIONS if any(res[m][c].get("num_cases") for m in methods)]
    lines = [f"Shape completion, {res['num_cases']} cases, source: {res['source']} "
             f"(mean over cases" + (f" and seeds {seeds}" if len(seeds) > 1 else "") +
             f"; seconds = fruit completion per fruit, {res['threads']} torch threads)", "",
             "| condition | method | Chamfer (cm) | volume err (cm^3) | centre err (cm) "
             "| angle err (deg) | s/fruit |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for cond in conds:
        for m in methods:
            r = res[m][cond]
            lines.append(f"| {cond.replace('_', ' ')} | {NAMES[m]} | {r['chamfer_cm']:.2f} | "
                         f"{r['volume_err_cm3']:.1f} | {r['center_err_cm']:.2f} | "
                         f"{r['angle_err_deg']:.1f} | {r['seconds']:.2f} |")
    ivs = [(cond, m) for cond in conds for m in methods
           if "volume_interval_coverage" in res[m][cond]]
    if ivs:
        lines += ["", "Volume intervals of the hypothesis sets (coverage of the true volume / "
                  "mean width over the true volume):", ""]
        lines += [f"- {cond.replace('_', ' ')}, {NAMES[m]}: "
                  f"{res[m][cond]['volume_interval_coverage']:.2f} / "
                  f"{res[m][cond]['volume_interval_width']:.2f}" for cond, m in ivs]
    if "seed_std" in res:
        lines += ["", "Standard deviation over seeds of the mean (Chamfer / volume / centre / "
                  "angle):", ""]
        for cond in conds:
            for m in methods:
                r = res["seed_std"][m][cond]
                lines.append(f"- {cond.replace('_', ' ')}, {NAMES[m]}: {r['chamfer_cm']:.3f} / "
                             f"{r['volume_err_cm3']:.2f} / {r['center_err_cm']:.3f} / "
                             f"{r['angle_err_deg']:.2f}")
    if res.get("per_fruit"):
        lines += ["", "Per fruit (Chamfer cm / volume err cm^3 / centre err cm / angle err deg; "
                  "mean over the scenes it was placed in):", "",
                  "| fruit | volume (cm^3) | scenes | condition | " +
                  " | ".join(NAMES[m] for m in methods) + " |",
                  "| --- | --- | --- | --- | " + " | ".join("---" for _ in methods) + " |"]
        for fruit, d in res["per_fruit"].items():
            for cond in conds:
                cells = []
                for m in methods:
                    r = d[m][cond]
                    cells.append(f"{r['chamfer_cm']:.2f} / {r['volume_err_cm3']:.1f} / "
                                 f"{r['center_err_cm']:.2f} / {r['angle_err_deg']:.1f}")
                lines.append(f"| {fruit} | {res['fruits'][fruit]['volume_cm3']:.0f} | "
                             f"{d[methods[0]][cond]['num_cases']} | {cond.replace('_', ' ')} | "
                             + " | ".join(cells) + " |")
        if res.get("skipped"):
            lines += ["", f"{len(res['skipped'])} fruit-scene pairs could not be built and "
                      "are left out (`skipped` in the JSON)."]
    lines += ["", "TCoRe is not evaluated: its trained weights are not available."]
    return "\n".join(lines) + "\n"


def RunShapeTable(a: ShapeTableOptions) -> None:
    """The table (see the module docstring): writes ``a.out``, its Markdown
    and pictures, and prints the Markdown. Raises InputError for a bad
    option or mesh file (before any work) or when no case could be built."""
    if a.figures < 0:
        raise InputError(f"--figures must be >= 0, got {a.figures}")
    fruit_files, fruits = None, {}
    if a.fruit_mesh_dir:
        fruit_files = FruitMeshFolder(a.fruit_mesh_dir)
        for name, (f, ped) in fruit_files.items():   # every file checked before any work
            fm = LoadFruitMesh(str(f), str(ped) if ped else "")
            fruits[name] = {"file": str(f), "peduncle_file": str(ped) if ped else "",
                            "volume_cm3": fm.volume * 1e6,
                            "extents_cm": [float(x) * 100 for x in fm.mesh.extents],
                            "repairs": fm.repairs}
    names = a.scenario_names.split(",") if a.scenario_names else None
    torch.set_num_threads(a.threads)
    methods = a.methods.split(",")
    conditions = a.conditions.split(",")
    bad = [c for c in conditions if c not in CONDITIONS]
    if bad:
        raise InputError(f"--conditions: unknown {bad[0]!r} (choose from {', '.join(CONDITIONS)})")
    cfg = yaml_load_typed(schema=ShapeConfig, defaults=ShapeConfig(),
                          data=MigrateScenarioText(a.shape_text, "--shape_text", named=False,
                                                   section="shape"))
    dec, mean, _ = LoadDecoder(cfg.weights_file, getattr(cfg, "mean_latent_file", "") or None)
    P = dc.replace(cfg.ssc, iterations=a.iterations) if a.iterations else cfg.ssc
    seeds = [int(x) for x in a.seeds.split(",")]
    rows, skipped = [], []
    t_all = time.time()
    out = Path(a.out)
    figures = out.parent / (out.stem + "_figures")
    figures_tmp = figures.with_name(figures.name + ".partial")
    if a.figures:
        shutil.rmtree(figures_tmp, ignore_errors=True)
        figures_tmp.mkdir(parents=True)
    todo = list(Cases(a.source, a.num_cases, fruit_files, names))
    bar = Progress(len(todo), desc="shape", unit="case").__enter__()
    try:
        _Evaluate(todo, conditions, seeds, methods, P, cfg, dec, mean, a.figures, figures_tmp,
                  rows, skipped, bar)
    finally:
        bar.__exit__(None, None, None)
    source = todo[0][0] if todo else None
    res = {"source": source, "num_cases": len({r["case"] for r in rows}), "threads": a.threads,
           "iterations": P.iterations, "seeds": seeds,
           "total_seconds": round(time.time() - t_all, 1)}
    if not rows:
        shutil.rmtree(figures_tmp, ignore_errors=True)
        raise InputError("no case could be built" + (
            f" ({len(skipped)} skipped: {skipped[0]['reason']})" if skipped else ""))
    res.update(Means(rows, methods))
    if fruit_files is not None:
        res["fruit_mesh_dir"] = str(a.fruit_mesh_dir)
        res["fruits"] = fruits
        res["per_fruit"] = {f: Means([r for r in rows if r["fruit"] == f], methods)
                            for f in fruits if any(r["fruit"] == f for r in rows)}
        res["skipped"] = skipped
    if len(seeds) > 1:
        res["seed_std"] = {m: {cond: {k: float(np.std([np.mean(
            [r[k] for r in rows if r["method"] == m and r["condition"] == cond
             and r["seed"] == sd]) for sd in seeds])) for k in METRICS} for cond in CONDITIONS}
            for m in methods}
    res["rows"] = rows
    out.parent.mkdir(parents=True, exist_ok=True)
    md = Markdown(res, methods)
    md_path = Path(a.md or out.with_suffix(".md"))
    if a.figures:       # the figures first: a complete JSON comes with its pictures
        shutil.rmtree(figures, ignore_errors=True)
        figures_tmp.replace(figures)
        res["figures"] = str(figures)
        md += f"\nPictures of the first {a.figures} case(s) of each fruit: `{figures}/`.\n"
    for path, text in ((md_path, md), (out, json.dumps(res, indent=1))):
        tmp = path.with_name(path.name + ".partial")
        tmp.write_text(text)
        tmp.replace(path)
    print(md)


def _Evaluate(todo, conditions, seeds, methods, P, cfg, dec, mean, n_figures, figures_dir,
              rows, skipped, bar) -> None:
    """Fits every method to every case of ``todo`` (``Cases`` items), appending
    the metric rows to ``rows`` and the scenes a fruit could not be placed in
    to ``skipped``; pictures of the first ``n_figures`` cases of each fruit
    into ``figures_dir``."""
    drawn: dict = {}
    for src, name, fruit, make in todo:
        try:
            cases = {cond: make(cond == "initial_occlusion") for cond in conditions}
        except PlantGenerationError as err:
            if not fruit:
                raise
            skipped.append({"case": name, "fruit": fruit, "reason": str(err)})
            bar.Say(f"{name:28s} skipped: {err}")
            bar.Step()
            continue
        draw = drawn.get(fruit, 0) < n_figures
        drawn[fruit] = drawn.get(fruit, 0) + 1
        for cond in conditions:
            case = cases[cond]
            sem = case.semantic
            negatives = None
            for seed in seeds:
                P.seed = seed
                fits, scores = {}, {}
                for m in methods:
                    tm = {}
                    est = CompleteScene(sem, dec, mean, P, m, cfg.free_space_voxel, timings=tm)
                    f = est.fruit
                    r = ShapeMetrics(f.vertices_W, f.faces, f.peduncle_axis_W,
                                     case.gt_vertices_W, case.gt_faces, case.gt_axis_W)
                    r.update(seconds=tm.get("fruit_s", 0.0),
                             branch_seconds=tm.get("branch_s", 0.0), case=case.name,
                             condition=cond, method=m, seed=seed, fruit=fruit,
                             visible_fraction=case.visible_fraction,
                             num_fruit_points=int(len(sem.fruit_points_W)),
                             volume_cm3=abs(MeshVolume(f.vertices_W, f.faces)) * 1e6,
                             gt_volume_cm3=abs(MeshVolume(case.gt_vertices_W,
                                                          case.gt_faces)) * 1e6,
                             scale=float(np.cbrt(abs(np.linalg.det(f.X_WO[:3, :3])))),
                             **CentreOffsetCm(f, case, sem))
                    if f.hypotheses is not None:
                        lo, hi = (float(x) for x in f.hypotheses.volume_interval_cm3)
                        gv = r["gt_volume_cm3"]
                        r.update(volume_interval_cm3=[lo, hi],
                                 volume_in_interval=bool(lo <= gv <= hi),
                                 volume_interval_rel_width=(hi - lo) / gv,
                                 num_hypotheses=len(f.hypotheses.volume_cm3),
                                 hypotheses_seconds=tm.get("hypotheses_s", 0.0))
                    if m != "supeps":
                        if negatives is None:
                            negatives = SceneNegatives(sem, cfg.free_space_voxel)
                        tr = [t for t in f.loss_trace if t.get("it", -1) >= 0]
                        r.update(neg_iters=int(sum(t["neg"] > 0 for t in tr)),
                                 ped_iters=int(sum(t["ped"] > 0 for t in tr)),
                                 neg_inside=int((f.sdf_W(negatives) < -5e-4).sum()))
                    rows.append(r)
                    fits[m], scores[m] = f, r
                    bar.Say(f"{case.name:28s} {cond:18s} {m:7s} s{seed} CD {r['chamfer_cm']:.2f} cm"
                            f"  V {r['volume_err_cm3']:6.1f} cm3  c {r['center_err_cm']:.2f} cm  "
                            f"ang {r['angle_err_deg']:5.1f} deg  {r['seconds']:.2f} s  "
                            f"(vis {case.visible_fraction:.2f})")
                if draw and seed == seeds[0]:
                    ShapeCaseFigure(sem, case.gt_vertices_W, case.gt_center_W, fits, scores,
                                    figures_dir / f"{_FileName(case.name)}_{cond}.png",
                                    title=f"{case.name}, {cond.replace('_', ' ')} "
                                          f"(visible {case.visible_fraction:.0%})")
        bar.Step()


def _FileName(name: str) -> str:
    """A case name as a file name (``fruit@scene``: ``@`` kept)."""
    return "".join(ch if ch.isalnum() or ch in "@._-" else "_" for ch in name)
