"""Segmentation IoU per backend against the simulator's labels: on
scenarios rendered here, or on recorded runs' views that carry labels.

    python scripts/eval_segmentation.py --out out/seg.json
    python scripts/eval_segmentation.py --scenario_file diagrams/default.yaml \
        --scenario_names Defaults OneOfEverything --backends color_depth label --out seg.json
    python scripts/eval_segmentation.py --scenarios 30 --seed 21 --out seg_random.json

Images come from the scenario's camera: the noisy L515-like model by default
(``--scenario_text "{camera_noise: {enabled: false}}"`` for perfect images).
``--scenarios N --seed S`` evaluates ``RandomSuite(N, S)`` instead of a file.

Default scenarios: every scenario in diagrams/suite.yaml if that file exists,
otherwise Defaults and OneOfEverything from diagrams/default.yaml.

Writes JSON: ``{backend: {"mean": {"fruit_iou", "leaf_iou", "branch_iou"},
"pooled": {the same, over every view's pixels together}, "mean_non_green": {...},
"mean_green": {...}, "phantom_fruits_per_view",
"per_fruit_color": {colour: {"fruit_iou", "views"}}, "scenarios": {name: {...}}}}``.
IoU is over pixels; the robot counts as background, a neighbouring plant's
pixels (the greenhouse's next row) are left out. A class absent from both
the truth and the prediction has IoU null and is left out of the means.
``fruit_color`` (red / orange / yellow / green, from the rendered truth
pixels' hue) lets green peppers be reported separately. Per scenario,
``fruit_instances`` lists the backend's fruit instances of 50 pixels or
more with the truth fractions of their pixels (fruit / branch / leaf;
``FruitInstanceTruth``); ``phantoms`` counts those mostly not fruit (a
side shoot or stalk taken for a fruit: the planner would complete and
reveal a fruit that is not there), summed in each backend's
``instances`` and averaged per view in ``phantom_fruits_per_view``
(``phantom_fruits_per_view_no_overlap``: those with no true fruit pixel at
all). ``leaf_instances`` scores the backend's leaf instances against the true
leaves (``perception.leaf_instances.LeafInstanceScores``: per view the
best IoU of each true leaf of 200 pixels or more, matched at IoU 0.5,
merges, splits; per backend ``matched_fraction``, ``mean_best_iou``,
``merges_per_view``, ``splits_per_view``; docs/explanation/leaf-instances.md);
``leaf_boundary`` the backend's leaf boundary band against the true seams
(``labels.LeafBoundaryMask``) on the true leaf pixels: pooled
``precision`` and ``recall`` (null for a backend without a band).
``fruit_colors`` gives per view the fruit IoU of each true fruit
colour (the fruit pixels of the other colours left out; phantom fruit
counts against every colour) and its recall (the share of that colour's
fruit pixels called fruit). Multi-fruit plants:

    python scripts/eval_segmentation.py --scenario_file diagrams/multi_suite.yaml \
        --settle 0.3 --backends segnet --out out/seg_multi.json

Recorded runs (``EvalRecordings``): every ``DIR/*/recording/`` whose views
carry ``view<k>_label.npy``; the same keys with ``views`` ({"<run>/view<k>":
row}) instead of ``scenarios``, and a picture per view (the colour image,
the truth and each backend's classes over it, phantom fruit boxed) in
``<out>_views/``:

    python scripts/eval_segmentation.py --recordings out/ --backends segnet,color_depth,label \
        --out out/seg_recordings.json
"""
from __future__ import annotations

import dataclasses as dc
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from lmap_drake.errors import InputError
from lmap_drake.labels import (BRANCH, FRUIT, LEAF, ROBOT, DecodeLabels, LeafBoundaryMask,
                               NeighbourClassMap)
from lmap_drake.perception.leaf_boundaries import BandCounts, BandPrecisionRecall
from lmap_drake.perception.leaf_instances import LeafInstanceScores, SummariseLeafInstances
from lmap_drake.paths import REPO_ROOT as REPO
from lmap_drake.perception.points import Intrinsics
from lmap_drake.perception.recording import LoadRecording
from lmap_drake.planning.config import PlannerConfig
from lmap_drake.perception.segmentation import (ClassIou, FruitInstanceTruth, MakeSegmenter,
                                                RgbToHsv, TruthClassMap)
from lmap_drake.viz import SavePng
from lmap_drake.plants.suite import RandomSuite, SuiteYaml
from lmap_drake.plants.plant_station import RenderStill
from lmap_drake.scenario import LoadScenario, ScenarioNames
from lmap_drake.station.camera_noise import CameraProfile

CLASSES = (("fruit_iou", 3), ("leaf_iou", 2), ("branch_iou", 1))


def DefaultScenarios() -> tuple[Path, list[str]]:
    """The default scenario file and names ([] = every scenario in it)."""
    suite = REPO / "diagrams" / "suite.yaml"
    if suite.exists():
        return suite, []  # [] = every scenario in the file
    return REPO / "diagrams" / "default.yaml", ["Defaults", "OneOfEverything"]


def _fruit_color(rgb: np.ndarray, truth: np.ndarray) -> str | None:
    """Colour name of the pixels ``truth == 3`` (None: none; "unknown": too
    few lit pixels to tell)."""
    m = truth == 3
    if m.sum() == 0:
        return None
    hsv = RgbToHsv(rgb[..., :3])
    if (m & (hsv[..., 2] >= 0.08)).sum() < 10:
        return "unknown"
    h = hsv[..., 0][m & (hsv[..., 2] >= 0.08)]
    hue = float(np.degrees(np.angle(np.mean(np.exp(1j * np.radians(h))))) % 360)
    if hue >= 330 or hue < 15:
        return "red"
    if hue < 40:
        return "orange"
    if hue < 70:
        return "yellow"
    return "green"


def _mean(rows: list[dict]) -> dict:
    out = {}
    for key, _ in CLASSES:
        vals = [r[key] for r in rows if r.get(key) is not None]
        out[key] = float(np.mean(vals)) if vals else None
        out[key.replace("_iou", "_n")] = len(vals)
    return out


def ViewRow(seg, truth: np.ndarray, label: np.ndarray, rgb: np.ndarray) -> dict:
    """One view's figures for one backend's ``seg``: IoU per class, fruit
    instances with the truth of their pixels, phantoms (mostly not fruit;
    and with no fruit pixel at all), fruit IoU per true fruit colour. The
    pixels of a neighbouring plant (``labels.NeighbourClassMap``: the
    greenhouse's next row) are left out of the class IoUs (neither right
    nor wrong); a fruit instance on them still counts as a phantom (they
    bear no fruit)."""
    row = {}
    keep = NeighbourClassMap(label) == 0
    row["neighbour_pixels"] = int((~keep).sum())
    row["pixels"] = {}             # per class: [intersection, union] pixel counts
    for key, c in CLASSES:
        a, b = seg.class_map[keep] == c, truth[keep] == c
        inter, union = int((a & b).sum()), int((a | b).sum())
        row[key] = round(inter / union, 4) if union else None   # ClassIou's, NaN as None
        row["pixels"][key] = [inter, union]
    # the same without the robot's pixels: what reaches the planner, whose
    # points pass the robot self-filter (perception.points, from the joints)
    cls, inst = DecodeLabels(label)
    plant = keep & (cls != ROBOT)
    row["without_robot"] = {}
    for key, c in CLASSES:
        v = ClassIou(seg.class_map[plant], truth[plant], c)
        row["without_robot"][key] = None if math.isnan(v) else round(v, 4)
    row["flags"] = seg.flags
    row["fruit_instances"] = FruitInstanceTruth(seg, truth)
    row["phantoms"] = sum(r["fruit"] < 0.5 for r in row["fruit_instances"])
    row["phantoms_no_overlap"] = sum(r["fruit"] == 0.0 for r in row["fruit_instances"])
    # phantoms the planner could take for a target (planner.min_fruit_confidence)
    bar = PlannerConfig().min_fruit_confidence
    row["phantoms_confident"] = sum(r["fruit"] < 0.5 and (r["confidence"] is None
                                                          or r["confidence"] >= bar)
                                    for r in row["fruit_instances"])
    row["leaf_instances"] = LeafInstanceScores(
        np.where(seg.class_map == LEAF, seg.instance_map, -1), np.where(cls == LEAF, inst, -1),
        ignore=~keep)
    if getattr(seg, "leaf_boundary", None) is not None:   # the band against the true seams
        true_leaf = keep & (cls == LEAF)
        hit, said, true = BandCounts(np.asarray(seg.leaf_boundary, bool)[true_leaf],
                                     LeafBoundaryMask(np.where(true_leaf, inst, -1))[true_leaf])
        row["leaf_boundary"] = {"true_px": int(true), "predicted_px": int(said),
                                "hit_px": int(hit)}
    colors = {}
    for i in np.unique(inst[cls == FRUIT]):
        colors.setdefault(_fruit_color(rgb, np.where((cls == FRUIT) & (inst == i), 3, 0)),
                          []).append(i)
    pred = seg.class_map == FRUIT
    row["fruit_colors"] = {}
    for color, ids in sorted(colors.items()):
        mine = (cls == FRUIT) & np.isin(inst, ids)
        p = pred & ~((truth == FRUIT) & ~mine)
        row["fruit_colors"][color] = {
            "fruit_iou": round(float((p & mine).sum() / max((p | mine).sum(), 1)), 4),
            "fruit_recall": round(float((pred & mine).sum() / max(mine.sum(), 1)), 4)}
    return row


def Summary(rows: list[dict]) -> dict:
    """Means over the rows (views) without an error: per class, per fruit
    colour, phantoms per view."""
    rows = [r for r in rows if "error" not in r]
    m = _mean(rows)
    colors = sorted({c for r in rows for c in r["fruit_colors"]})
    n = max(len(rows), 1)
    return {"mean": {k: v for k, v in m.items() if k.endswith("_iou")},
            "pooled": _Pooled(rows),
            "mean_without_robot": {k: v for k, v in _mean(
                [r["without_robot"] for r in rows if "without_robot" in r]).items()
                if k.endswith("_iou")},
            "counts": {k: v for k, v in m.items() if k.endswith("_n")},
            "mean_non_green": _mean([r for r in rows if r["fruit_color"] != "green"]),
            "mean_green": _mean([r for r in rows if r["fruit_color"] == "green"]),
            "per_fruit_color": {c: {k: round(float(np.mean(
                [r["fruit_colors"][c][k] for r in rows if c in r["fruit_colors"]])), 4)
                for k in ("fruit_iou", "fruit_recall")} | {
                "views": sum(c in r["fruit_colors"] for r in rows)} for c in colors},
            "phantom_fruits_per_view": round(sum(r["phantoms"] for r in rows) / n, 3),
            "phantom_fruits_per_view_confident": round(
                sum(r.get("phantoms_confident", 0) for r in rows) / n, 3),
            "phantom_fruits_per_view_no_overlap": round(
                sum(r["phantoms_no_overlap"] for r in rows) / n, 3),
            "leaf_instances": SummariseLeafInstances([r["leaf_instances"] for r in rows]),
            "leaf_boundary": _BoundarySummary([r["leaf_boundary"] for r in rows
                                               if "leaf_boundary" in r]),
            "instances": {"fruit_instances": sum(len(r["fruit_instances"]) for r in rows),
                          "phantoms": sum(r["phantoms"] for r in rows)},
            "views_evaluated": len(rows)}


def _Pooled(rows: list[dict]) -> dict:
    """Per class, the IoU of every view's pixels together (the sums of the
    intersections over the sums of the unions; None with no pixel of the
    class anywhere): the dataset-level IoU of the segmentation benchmarks.
    Beside the per-view ``mean``, in which a view with no true fruit and a
    few pixels called fruit scores 0 and weighs as much as any other."""
    out = {}
    for key, _ in CLASSES:
        pairs = [r["pixels"][key] for r in rows if "pixels" in r]
        union = sum(u for _, u in pairs)
        out[key] = round(sum(i for i, _ in pairs) / union, 4) if union else None
    return out


def _BoundarySummary(rows: list[dict]) -> dict | None:
    """Pooled ``precision`` and ``recall`` of a backend's leaf boundary band
    (None when it gives none)."""
    if not rows:
        return None
    precision, recall = BandPrecisionRecall(
        [sum(r[k] for r in rows) for k in ("hit_px", "predicted_px", "true_px")])
    return {"precision": precision, "recall": recall, "views": len(rows)}


def Evaluate(scenario_file: Path, names: list[str], backends: list[str],
             scenario_text: str = "{}", settle: float = 0.0, log=print) -> dict:
    names = names or ScenarioNames(scenario_file)
    results = {b: {"scenarios": {}} for b in backends}
    for name in tqdm(names, desc="eval_segmentation", unit="scene", file=sys.stderr):
        s = LoadScenario(filename=scenario_file, scenario_name=name, scenario_text=scenario_text)
        t0 = time.time()
        rgb, depth, label = RenderStill(s, settle)
        truth = TruthClassMap(label)
        color = _fruit_color(rgb, truth)
        K = Intrinsics.FromCameraConfig(s.cameras["camera0"])
        for backend in backends:
            cfg = dc.replace(s.perception, segmenter=backend)
            row = {"fruit_color": color,
                   "truth_pixels": {k.replace("_iou", ""): int((truth == c).sum())
                                    for k, c in CLASSES}}
            try:
                t1 = time.time()
                seg = MakeSegmenter(cfg, K).Segment(rgb, depth, label)
                row["seconds"] = round(time.time() - t1, 3)
                row.update(ViewRow(seg, truth, label, rgb))
            except Exception as err:  # e.g. grounded_sam without weights
                row["error"] = f"{type(err).__name__}: {err}"
            results[backend]["scenarios"][name] = row
            log(f"{name:24s} {backend:12s} " + (row.get("error") or " ".join(
                f"{k}={row[k]}" for k, _ in CLASSES)) + f"  fruit={color}")
        log(f"  ({time.time() - t0:.1f} s)")
    for res in results.values():
        res.update(Summary(list(res["scenarios"].values())))
    return results


def EvalSegmentation(out, scenario_file: Path | None = None, scenario_names: list | None = None,
                     backends: list[str] = ("segnet", "color_depth", "label"), scenarios: int = 0,
                     seed: int = 0, scenario_text: str = "{}", settle: float = 0.0) -> dict:
    """``Evaluate`` on ``scenario_file`` (default: ``DefaultScenarios``) or,
    with ``scenarios`` > 0, on ``RandomSuite(scenarios, seed)`` (written
    beside ``out`` as ``.suite.yaml``); writes ``out`` (JSON, with
    ``_meta``), prints one line per backend and returns the result."""
    file_default, names_default = DefaultScenarios()
    backends = list(backends)
    file = scenario_file or file_default
    if scenarios:
        file = Path(out).with_suffix(".suite.yaml")
        file.parent.mkdir(parents=True, exist_ok=True)
        file.write_text(SuiteYaml(RandomSuite(scenarios, seed),
                                  f"# RandomSuite({scenarios}, {seed})"))
    if scenario_names is not None:
        names = scenario_names
    else:
        names = names_default if (scenario_file is None and not scenarios) else []
    res = Evaluate(file, names, backends, scenario_text, settle)
    res["_meta"] = {"camera": CameraProfile(LoadScenario(scenario_text=scenario_text)
                                            .camera_noise),
                    "scenario_file": str(file),
                    "scenario_text": scenario_text, "settle": settle}
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_text(json.dumps(res, indent=2))
    for b in backends:
        g, o = res[b]["mean_green"], res[b]["mean_non_green"]
        print(f"{b:12s} mean {res[b]['mean']}  pooled {res[b]['pooled']}  "
              f"fruit IoU green {g['fruit_iou']} "
              f"(n={g['fruit_n']}), others {o['fruit_iou']} (n={o['fruit_n']}); phantom fruit "
              f"instances {res[b]['instances']['phantoms']} of "
              f"{res[b]['instances']['fruit_instances']}")
    return res


# ----------------------------------------------------------------------------
# Recorded runs.

CLASS_COLORS = {BRANCH: (150, 90, 30), LEAF: (40, 200, 60), FRUIT: (240, 40, 200)}


class RecordingsError(InputError):
    """The recordings folder is missing or holds no labelled view."""


def LabelledRecordings(folder) -> list[tuple[str, object]]:
    """(run name, ``Recording``) of every ``folder/*/recording/`` (or
    ``folder`` itself when it is a run) with at least one labelled view,
    sorted by name; ``RecordingsError`` naming the folder when there is
    none, a recording's own ``RecordingError`` when one is malformed."""
    folder = Path(folder)
    if not folder.is_dir():
        raise RecordingsError(f"--recordings {folder}: no such folder")
    runs = [folder] if (folder / "recording" / "recording.json").is_file() else sorted(
        d for d in folder.iterdir() if (d / "recording" / "recording.json").is_file())
    out = []
    for run in runs:
        rec = LoadRecording(run)
        if any(v.label is not None for v in rec.views):
            out.append((run.name, rec))
    if not out:
        raise RecordingsError(f"--recordings {folder}: no run folder with a labelled "
                              f"recording (<run>/recording/view<k>_label.npy) in it")
    return out


def _Intrinsics(cam: dict) -> Intrinsics:
    return Intrinsics(int(cam["width"]), int(cam["height"]), float(cam["fx"]),
                      float(cam["fy"]), float(cam["cx"]), float(cam["cy"]))


def OverlayClasses(rgb: np.ndarray, class_map: np.ndarray, title: str,
                   boxes: list = ()) -> np.ndarray:
    """HxWx3 picture: the classes' colours (branch brown, leaf green, fruit
    magenta) over the dimmed image, ``boxes`` (x0, y0, x1, y1) drawn in
    red, ``title`` top left."""
    from PIL import Image, ImageDraw
    img = rgb[..., :3].astype(np.float64) * 0.5
    for c, col in CLASS_COLORS.items():
        m = class_map == c
        img[m] = 0.4 * img[m] + 0.6 * np.array(col)
    im = Image.fromarray(img.clip(0, 255).astype(np.uint8))
    draw = ImageDraw.Draw(im)
    for b in boxes:
        draw.rectangle([int(x) for x in b], outline=(255, 0, 0), width=2)
    draw.rectangle([0, 0, 8 + 7 * len(title), 14], fill=(0, 0, 0))
    draw.text((4, 2), title, fill=(255, 255, 255))
    return np.asarray(im)


def _PhantomBoxes(seg, truth: np.ndarray, min_pixels: int = 50) -> list:
    boxes = []
    fruit = seg.class_map == FRUIT
    for i in np.unique(seg.instance_map[fruit]):
        m = fruit & (seg.instance_map == i)
        if m.sum() >= min_pixels and np.mean(truth[m] == FRUIT) < 0.5:
            ys, xs = np.nonzero(m)
            boxes.append((xs.min(), ys.min(), xs.max(), ys.max()))
    return boxes


def EvalRecordings(out, recordings, backends=("segnet", "color_depth", "label"),
                   scenario_text: str = "{}", pictures: bool = True) -> dict:
    """Evaluates ``backends`` on every labelled view of the recorded runs
    under ``recordings`` (``LabelledRecordings``) with the perception
    settings of the default scenario plus ``scenario_text``; writes ``out``
    (JSON, keys as in the module docstring) and, with ``pictures``, one PNG
    per view into ``<out>_views/``. Bad input (folder, recordings, backend
    files) fails before anything is written."""
    backends = list(backends)
    perception = LoadScenario(scenario_text=scenario_text).perception
    runs = LabelledRecordings(recordings)
    segmenters = {}
    for name, rec in runs:       # each backend built (weights read) before any view
        key = tuple(sorted(rec.camera.items()))
        for b in backends:
            if (b, key) not in segmenters:
                segmenters[(b, key)] = MakeSegmenter(dc.replace(perception, segmenter=b),
                                                     _Intrinsics(rec.camera))
    out = Path(out)
    views_dir = out.with_name(out.stem + "_views")
    results = {b: {"views": {}} for b in backends}
    todo = [(name, rec, v) for name, rec in runs for v in rec.views if v.label is not None]
    for name, rec, v in tqdm(todo, desc="eval_segmentation", unit="view", file=sys.stderr):
        key = tuple(sorted(rec.camera.items()))
        rgb = np.ascontiguousarray(v.rgb[..., :3])
        truth = TruthClassMap(v.label)
        view_name = f"{name}/view{v.index}"
        panels = [OverlayClasses(rgb, np.zeros_like(truth), f"{view_name} rgb"),
                  OverlayClasses(rgb, truth, "truth")]
        for b in backends:
            t0 = time.time()
            seg = segmenters[(b, key)].Segment(rgb, v.depth, v.label)
            row = {"fruit_color": _fruit_color(rgb, truth), "seconds": round(time.time() - t0, 3),
                   "truth_pixels": {k.replace("_iou", ""): int((truth == c).sum())
                                    for k, c in CLASSES}}
            row.update(ViewRow(seg, truth, v.label, rgb))
            row["instance_confidences"] = [
                {"class": c, "instance": i, "pixels": n,
                 "confidence": None if math.isnan(conf) else conf}
                for c, i, n, conf in seg.Instances()]
            results[b]["views"][view_name] = row
            panels.append(OverlayClasses(rgb, seg.class_map, f"{b}: fruit {row['fruit_iou']} "
                                         f"leaf {row['leaf_iou']} phantoms {row['phantoms']}",
                                         _PhantomBoxes(seg, truth)))
        if pictures:
            views_dir.mkdir(parents=True, exist_ok=True)
            grid = panels + [np.zeros_like(panels[0])] * (len(panels) % 2)
            SavePng(np.concatenate([np.concatenate(grid[i:i + 2], axis=1)
                                    for i in range(0, len(grid), 2)], axis=0),
                    views_dir / f"{name}_view{v.index}.png")
    for res in results.values():
        res.update(Summary(list(res["views"].values())))
    results["_meta"] = {"recordings": str(recordings), "runs": [n for n, _ in runs],
                        "views": len(todo), "scenario_text": scenario_text,
                        "pictures": str(views_dir) if pictures else None}
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".partial")
    tmp.write_text(json.dumps(results, indent=2))
    tmp.replace(out)                   # an interrupted run leaves no complete-looking JSON
    for b in backends:
        r = results[b]
        print(f"{b:12s} mean {r['mean']}  per fruit colour "
              f"{ {c: v['fruit_iou'] for c, v in r['per_fruit_color'].items()} }  phantom "
              f"fruit per view {r['phantom_fruits_per_view']} ({len(todo)} views)")
    return results
