"""How well the segmentation network sees a leaf while the gripper holds it,
on the recorded views of simulated episodes (``lmap-drake run`` writes
them to ``OUT/recording/``, with the renderer's labels).

    python scripts/eval_held_leaf.py --runs out/run1 out/run2 ... --out held.json
    python scripts/eval_held_leaf.py --runs out/*/ --weights old.pt models/segnet/segnet.pt \\
        --out held.json

A view is *held* when the gripper reads under 2 cm open; its held leaf is
the labelled leaf with the most points within 4 cm of the TCP (the
episode's scenario gives the robot's base, the view's joints the TCP):
``systems.planning.HeldLeaf`` on the labelled leaves' points. Per
weights file: the held leaf's recall (the fraction of its pixels the
network calls leaf), the recall of every other leaf in held views and of
every leaf in views without a held leaf, and the fruit IoU per view.
Views whose images repeat (the same episode run twice) count once.

Writes JSON: ``{weights: {"held_leaf_recall": {median, mean, below_0.5, n},
"other_leaf_recall": {...}, "rest_leaf_recall": {...}, "fruit_iou": {...},
"views": [...]}}``.
"""
from __future__ import annotations

import hashlib
import json
import sys
import time
from pathlib import Path

import numpy as np

from lmap_drake.errors import InputError
from lmap_drake.labels import FRUIT, LEAF, DecodeLabels
from lmap_drake.paths import REPO_ROOT
from lmap_drake.perception.points import DeprojectPixels, Intrinsics
from lmap_drake.perception.recording import LoadRecording
from lmap_drake.perception.segmentation import ClassIou, SegNetSegmenter, TruthClassMap
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.perception.config import PerceptionConfig
from lmap_drake.scenario import LoadScenario
from lmap_drake.systems.planning import HeldLeaf
from lmap_drake.types import SemanticScene

HELD_OPENING = 0.02   # m: the gripper reads less than this while it holds a leaf


def _summary(x: list[float]) -> dict:
    a = np.asarray(x, float)
    if not len(a):
        return {"n": 0}
    return {"n": int(len(a)), "median": round(float(np.median(a)), 4),
            "mean": round(float(a.mean()), 4), "below_0.5": int((a < 0.5).sum())}


def _RunViews(run: Path) -> list[dict]:
    """The labelled views of one episode folder: images, joints, gripper,
    camera, and its robot model."""
    rec = LoadRecording(run)
    c = rec.camera
    K = Intrinsics(int(c["width"]), int(c["height"]), float(c["fx"]), float(c["fy"]),
                   float(c["cx"]), float(c["cy"]))
    scenario = LoadScenario(filename=run / "scenario.yaml", scenario_text=[], bare=True)
    robot = RobotModel(scenario.robot.X_WB.GetDeterministicValue())
    out = []
    for v in rec.views:
        if v.label is None:
            continue
        out.append({"run": str(run), "index": v.index, "rgb": v.rgb, "depth": v.depth,
                    "label": v.label, "q": v.q, "gripper": v.gripper,
                    "X_WC": rec.X_WC, "K": K, "robot": robot})
    return out


def _LeafLabels(label: np.ndarray) -> list[int]:
    cls, _ = DecodeLabels(label)
    return [int(v) for v in np.unique(label[cls == LEAF])]


def HeldLeafLabel(view: dict) -> int | None:
    """The label of the held leaf in ``view`` (None when nothing is held):
    ``systems.planning.HeldLeaf`` on the labelled leaves' points."""
    if float(np.ravel(view["gripper"])[0]) >= HELD_OPENING:
        return None
    tcp = view["robot"].TcpPose(np.asarray(view["q"], float)).translation()
    labels = _LeafLabels(view["label"])
    pts = [DeprojectPixels(view["depth"], view["label"] == lab, view["K"], view["X_WC"])
           for lab in labels]
    held = HeldLeaf(SemanticScene(leaf_points_W=np.vstack(pts + [np.zeros((0, 3))]),
                                  leaf_instance=np.repeat(labels, [len(x) for x in pts])),
                    tcp)
    return None if held < 0 else held


def Evaluate(views: list[dict], weights: list[str]) -> dict:
    held = [HeldLeafLabel(v) for v in views]
    res = {}
    for w in weights:
        seg = SegNetSegmenter(views[0]["K"], w)
        rows, hl, ol, rl, fi = [], [], [], [], []
        for v, h in zip(views, held):
            cls = seg.Segment(v["rgb"], v["depth"]).class_map
            truth = TruthClassMap(v["label"])
            row = {"run": v["run"], "view": v["index"], "held_leaf": h, "leaves": {}}
            for lab in _LeafLabels(v["label"]):
                mask = v["label"] == lab
                if mask.sum() < 200:
                    continue
                r = float((cls[mask] == LEAF).mean())
                row["leaves"][int(lab)] = round(r, 4)
                (hl if h == int(lab) else ol if h is not None else rl).append(r)
            iou = ClassIou(cls, truth, FRUIT)
            if np.isfinite(iou):
                row["fruit_iou"] = round(float(iou), 4)
                fi.append(float(iou))
            rows.append(row)
        res[w] = {"held_leaf_recall": _summary(hl), "other_leaf_recall": _summary(ol),
                  "rest_leaf_recall": _summary(rl), "fruit_iou": _summary(fi), "views": rows}
    return res


def EvalHeldLeaf(runs: list[Path], weights: list[str] | None, out: Path) -> None:
    """Scores every weights file (default: the shipped one) on the labelled
    views of the episode folders ``runs`` (a view repeated across runs
    counts once) and writes ``out`` (JSON). A folder without a recording is
    skipped with a note on stderr. Raises InputError for a missing weights
    file, no folder with a recording, or no labelled view."""
    weights = weights or [str(REPO_ROOT / PerceptionConfig().segnet_weights)]
    for w in weights:
        if not Path(w).is_file():
            raise InputError(f"--weights: no such file: {w}")
    found = [r for r in runs if (r / "recording" / "recording.json").is_file()]
    for r in runs:
        if r not in found:
            print(f"note: {r}: no recording/recording.json, skipped", file=sys.stderr)
    if not found:
        raise InputError("--runs: no folder with a recording")
    t0 = time.time()
    views, seen = [], set()
    for r in found:
        for v in _RunViews(r):
            key = hashlib.sha1(np.ascontiguousarray(v["rgb"]).tobytes()).digest()
            if key not in seen:
                seen.add(key)
                views.append(v)
    if not views:
        raise InputError("the recordings hold no labelled views (hardware recordings have no "
                         "labels)")
    res = Evaluate(views, weights)
    res["meta"] = {"runs": [str(r) for r in found], "views": len(views),
                   "held_views": sum(1 for row in next(iter(res.values()))["views"]
                                     if row["held_leaf"] is not None),
                   "seconds": round(time.time() - t0, 1)}
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp")
    tmp.write_text(json.dumps(res, indent=1))
    tmp.replace(out)
    for w in weights:
        s = res[w]
        print(f"{w}: held leaf recall {s['held_leaf_recall']}; other leaves in held views "
              f"{s['other_leaf_recall']}; leaves without a held one {s['rest_leaf_recall']}; "
              f"fruit IoU {s['fruit_iou']}")
    print(f"{res['meta']['views']} views ({res['meta']['held_views']} held) -> {out}")
