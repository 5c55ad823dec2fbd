"""Rendered test views for the perception tests (small images, fast)."""
from __future__ import annotations

import dataclasses as dc

import numpy as np

from lmap_drake.perception.points import Intrinsics
from lmap_drake.scenario import LoadScenario
from lmap_drake.plants.plant_station import MakePlantStation

# 320x240 camera, closer and to the side so the fruit shows beside the leaf.
SMALL_CAMERA = ("cameras: {camera0: {name: camera0, width: 320, height: 240, "
                "focal: !FocalLength {x: 228.4, y: 228.5}, center_x: 160.0, center_y: 120.0, "
                "X_PB: {base_frame: world, translation: [0.25, -0.55, 0.45], "
                "rotation: !Rpy {deg: [-105.0, 0.0, -25.0]}}}}")

FRUIT_COLORS = {"red": [0.75, 0.05, 0.05], "yellow": [0.9, 0.75, 0.05],
                "orange": [0.95, 0.45, 0.05], "green": [0.15, 0.45, 0.08]}


@dc.dataclass
class View:
    rgb: np.ndarray      # HxWx4 uint8
    depth: np.ndarray    # HxW float32, m
    label: np.ndarray    # HxW int
    X_WC: np.ndarray     # 4x4
    K: Intrinsics
    scenario: object


# 320x240 camera below the fruit looking up at it (fruit well visible).
BELOW_CAMERA = SMALL_CAMERA.replace("[0.25, -0.55, 0.45]", "[0.5, -0.5, 0.12]").replace(
    "[-105.0, 0.0, -25.0]", "[-70.0, 0.0, 0.0]")


IDEAL_CAMERA = "{camera_noise: {enabled: false}}"


def Render(scenario_text: str = "", camera: str = SMALL_CAMERA, ideal: bool = True) -> View:
    """Renders camera0 of the default scenario with ``camera`` (a YAML
    ``cameras:`` override) and the extra overrides ``scenario_text``. With
    ``ideal`` (the default here: these views test algorithms on exact
    geometry) the camera model is off and the renderer's images are used."""
    text = camera + ("\n" + scenario_text if scenario_text else "")
    s = LoadScenario(scenario_text=[text] + ([IDEAL_CAMERA] if ideal else []))
    station = MakePlantStation(s)
    ctx = station.CreateDefaultContext()
    cam = s.cameras["camera0"]
    return View(
        rgb=np.array(station.GetOutputPort("camera0.rgb_image").Eval(ctx).data),
        depth=np.array(station.GetOutputPort("camera0.depth_image").Eval(ctx).data[..., 0]),
        label=np.array(station.GetOutputPort("camera0.label_image").Eval(ctx).data[..., 0]),
        X_WC=cam.X_PB.GetDeterministicValue().GetAsMatrix4(),
        K=Intrinsics.FromCameraConfig(cam), scenario=s)


def FruitColor(name: str) -> str:
    """Scenario override that paints the fruit (placeholder or plant-world
    schema)."""
    from lmap_drake.plants.config import PlantSceneConfig
    r, g, b = FRUIT_COLORS[name]
    rgba = f"{{rgba: [{r}, {g}, {b}, 1.0]}}"
    if hasattr(PlantSceneConfig(), "fruit_color"):
        return f"plant_scene: {{fruit_color: {rgba}}}"
    return f"plant_scene: {{fruit: {{color: {rgba}}}}}"
