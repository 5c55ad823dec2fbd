"""Recorded runs for the study tests: one rendered view of the default
scene (the perception tests' small 320x240 camera) saved in the project's
recording format."""
import dataclasses as dc

import numpy as np

from lmap_drake.perception.points import Intrinsics
from lmap_drake.perception.recording import CapturedView, SaveRecording
from lmap_drake.plants.plant_station import MakePlantStation
from lmap_drake.scenario import LoadScenario

CAMERA = ("cameras: {camera0: {name: camera0, width: 320, height: 240, "
          "focal: !FocalLength {x: 228.4, y: 228.5}, center_x: 160.0, center_y: 120.0, "
          "X_PB: {base_frame: world, translation: [0.25, -0.55, 0.45], "
          "rotation: !Rpy {deg: [-105.0, 0.0, -25.0]}}}}")


def RecordView(folder, with_label: bool = True, fruit_rgb: str | None = None,
               extra: str = "") -> CapturedView:
    """Renders camera0 (noisy camera model) and writes ``folder/recording/``;
    returns the view (with its label even when not recorded)."""
    text = [CAMERA] + ([f"plant_scene: {{fruit_color: {{rgba: [{fruit_rgb}, 1.0]}}}}"]
                       if fruit_rgb else []) + ([extra] if extra else [])
    s = LoadScenario(scenario_text=text)
    station = MakePlantStation(s)
    ctx = station.CreateDefaultContext()
    rgb = np.array(station.GetOutputPort("camera0.rgb_image").Eval(ctx).data)
    depth = np.array(station.GetOutputPort("camera0.depth_image").Eval(ctx).data[..., 0])
    label = np.array(station.GetOutputPort("camera0.label_image").Eval(ctx).data[..., 0])
    K = Intrinsics.FromCameraConfig(s.cameras["camera0"])
    view = CapturedView(0, 0.0, 0.0, rgb, depth, label,
                        np.zeros(6), np.zeros(6), np.full(3, np.nan))
    cam = {"width": K.width, "height": K.height, "fx": K.fx, "fy": K.fy, "cx": K.cx,
           "cy": K.cy}
    SaveRecording(folder, [view if with_label else dc.replace(view, label=None)], cam,
                  np.eye(4), "simulation")
    return view
