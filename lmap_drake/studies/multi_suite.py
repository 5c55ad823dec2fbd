"""Multi-fruit scenes rendered and measured (behind
``scripts/render_multi_suite.py``): camera0's colour and label images side
by side, leaf-leaf interpenetration at rest (after settling) and after a
push (each leaf in turn flicked toward its nearest neighbour leaf), the
simulated seconds per wall second, and per-fruit visibility.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from lmap_drake.labels import DecodeLabels
from lmap_drake.plants.leaf import BoundaryTriangles
from lmap_drake.plants.multi_geometry import LeafLeafPenetration, MeshesCross
from lmap_drake.plants.plant_sim import PlantWorldSim
from lmap_drake.plants.plant_station import RenderStill
from lmap_drake.scenario import LoadScenario
from lmap_drake.studies.shape_benchmark import SuiteScenarioNames

_CLASS_RGB = {1: (120, 80, 30), 2: (40, 170, 40), 3: (220, 40, 40), 4: (90, 90, 200)}


def LabelColors(label: np.ndarray) -> np.ndarray:
    """An RGB image (H, W, 3 uint8) of a label image: a colour per class,
    brightness varying with the instance."""
    cls, inst = DecodeLabels(label)
    out = np.full(cls.shape + (3,), 235, np.uint8)
    for c, rgb in _CLASS_RGB.items():
        m = cls == c
        if m.any():
            shade = 0.55 + 0.45 * ((inst[m] * 0.37) % 1.0)
            out[m] = (np.asarray(rgb)[None] * shade[:, None]).clip(0, 255).astype(np.uint8)
    return out


def RenderScenePng(scenario, path, rgb=None, label=None) -> None:
    """Writes camera0's colour image and its label colours side by side
    (``rgb``/``label`` given, or rendered with ``RenderStill``)."""
    if rgb is None:
        rgb, _, label = RenderStill(scenario)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate([np.asarray(rgb)[..., :3], LabelColors(label)], 1)).save(path)


def Interpenetration(world) -> dict:
    """Leaf-leaf interpenetration of a plant world's leaves: the deepest
    vertex (mm) and the pairs that overlap (deeper than 0.1 mm, or whose
    surfaces cross)."""
    Vs = [world.LeafVertices(j) for j in range(world.num_leaves)]
    tets = [r.tets for r in world.leaf_refs]
    P = LeafLeafPenetration(Vs, tets)
    surfs = [trimesh.Trimesh(V, BoundaryTriangles(T), process=False) for V, T in zip(Vs, tets)]
    pairs = [(a, b) for a in range(len(Vs)) for b in range(a + 1, len(Vs))
             if max(P[a, b], P[b, a]) > 1e-4 or MeshesCross(surfs[a], surfs[b])]
    return {"max_depth_mm": float(P.max() * 1e3), "pairs": pairs}


def MeasureScene(scenario, push: bool, out_png=None, push_speed: float = 1.5) -> dict:
    """Settles the scene 0.3 s, renders it, measures leaf interpenetration;
    with ``push`` flicks each leaf (its free vertices at ``push_speed`` m/s)
    toward its nearest neighbour leaf and measures over 0.3 s."""
    t0 = time.time()
    w = PlantWorldSim(scenario)
    build = time.time() - t0
    t0 = time.time()
    w.Hold(0.3)
    rate = 0.3 / (time.time() - t0)
    images = w.Images()
    if out_png:
        RenderScenePng(scenario, out_png, np.asarray(images["rgb_image"].data),
                       np.asarray(images["label_image"].data)[..., 0])
    m = w.model
    rec = {"leaves": w.num_leaves, "fruits": len(m.fruits), "build_s": round(build, 2),
           "sim_s_per_wall_s": round(rate, 3),
           "occlusion_predicted": [round(f.occlusion_predicted, 3) for f in m.fruits],
           "visibility_rendered": [round(w.Visibility(fruit=i), 3) for i in range(len(m.fruits))],
           "rest": Interpenetration(w), "pushes": []}
    if push:
        base = w.Fork()
        C = [lf.rest_W.mean(0) for lf in m.leaves]
        for j, leaf in enumerate(m.leaves):
            k = min((i for i in range(len(C)) if i != j),
                    key=lambda i: np.linalg.norm(C[i] - C[j]))
            d = C[k] - C[j]
            d /= np.linalg.norm(d)
            x = base.Fork()
            v = np.zeros((len(leaf.rest_W), 3))
            v[~leaf.fixed] = push_speed * d                 # m/s toward the neighbour
            x.deformable.SetVelocities(x.plant_context, x.leaf_ids[j], v.T)
            worst = {"max_depth_mm": 0.0, "pairs": [], "max_displacement_mm": 0.0}
            t0 = time.time()
            V0 = x.LeafVertices(j)
            for _ in range(6):
                x.Hold(0.05)
                worst["max_displacement_mm"] = max(worst["max_displacement_mm"], float(
                    np.linalg.norm(x.LeafVertices(j) - V0, axis=1).max() * 1e3))
                r = Interpenetration(x)
                worst["max_depth_mm"] = max(worst["max_depth_mm"], r["max_depth_mm"])
                worst["pairs"] = sorted(set(map(tuple, worst["pairs"])) | set(map(tuple, r["pairs"])))
            worst["settled"] = Interpenetration(x)
            worst.update(leaf=j, toward=k, wall_s=round(time.time() - t0, 2))
            rec["pushes"].append(worst)
    return rec


def MeasureSuite(suite: str, out: str | Path, scenario_text: str = "{}", push: bool = True,
                 push_speed: float = 1.5, only: str = "") -> dict:
    """``MeasureScene`` on every scene of a suite YAML (or those named in
    ``only``, comma-separated): ``out/NAME.png`` per scene and
    ``out/measurements.json``; prints a line per scene."""
    names = SuiteScenarioNames(suite)
    if only:
        names = [n for n in names if n in only.split(",")]
    out = Path(out)
    results = {}
    for name in names:
        s = LoadScenario(filename=suite, scenario_name=name, scenario_text=scenario_text)
        rec = MeasureScene(s, push, out / f"{name}.png", push_speed)
        results[name] = rec
        pushed = sum(bool(x["pairs"]) for x in rec["pushes"])
        print(f"{name}: {rec['fruits']} fruits, {rec['leaves']} leaves, "
              f"{rec['sim_s_per_wall_s']} sim s/wall s, rest interpenetration "
              f"{rec['rest']['max_depth_mm']:.2f} mm {rec['rest']['pairs']}, pushes with "
              f"interpenetration {pushed}/{len(rec['pushes'])} (max displacement "
              f"{max([x['max_displacement_mm'] for x in rec['pushes']] or [0]):.0f} mm)",
              flush=True)
    out.mkdir(parents=True, exist_ok=True)
    (out / "measurements.json").write_text(json.dumps(results, indent=1))
    print(f"wrote {len(names)} images and measurements.json to {out}")
    return results
