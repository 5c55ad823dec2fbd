"""lmap_drake.studies.segmentation on recorded runs (``scripts/eval_segmentation.py
--recordings DIR``): every labelled DIR/*/recording/, JSON per backend, view
and fruit colour, a picture per view; bad folders fail in one line."""
import json
import runpy

import numpy as np
import pytest

from lmap_drake.errors import InputError
from lmap_drake.paths import REPO_ROOT
from lmap_drake.perception.points import Intrinsics
from lmap_drake.perception.recording import CapturedView, SaveRecording
from lmap_drake.plants.plant_station import MakePlantStation
from lmap_drake.scenario import LoadScenario
from lmap_drake.studies.segmentation import EvalRecordings

# the perception tests' small camera (320x240), beside the fruit
CAMERA = ("cameras: {camera0: {name: camera0, width: 320, height: 240, "
          "focal: !FocalLength {x: 228.4, y: 228.5}, center_x: 160.0, center_y: 120.0, "
          "X_PB: {base_frame: world, translation: [0.25, -0.55, 0.45], "
          "rotation: !Rpy {deg: [-105.0, 0.0, -25.0]}}}}")


def _Record(folder, with_label: bool, fruit_rgb=None):
    text = [CAMERA] + ([f"plant_scene: {{fruit_color: {{rgba: [{fruit_rgb}, 1.0]}}}}"]
                       if fruit_rgb else [])
    s = LoadScenario(scenario_text=text)
    station = MakePlantStation(s)
    ctx = station.CreateDefaultContext()
    rgb = np.array(station.GetOutputPort("camera0.rgb_image").Eval(ctx).data)
    depth = np.array(station.GetOutputPort("camera0.depth_image").Eval(ctx).data[..., 0])
    label = np.array(station.GetOutputPort("camera0.label_image").Eval(ctx).data[..., 0])
    K = Intrinsics.FromCameraConfig(s.cameras["camera0"])
    view = CapturedView(0, 0.0, 0.0, rgb, depth, label if with_label else None,
                        np.zeros(6), np.zeros(6), np.full(3, np.nan))
    cam = {"width": K.width, "height": K.height, "fx": K.fx, "fy": K.fy, "cx": K.cx,
           "cy": K.cy}
    SaveRecording(folder, [view], cam, np.eye(4), "simulation")


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    _Record(root / "run_red", True)
    _Record(root / "run_green", True, "0.15, 0.45, 0.08")
    _Record(root / "run_unlabelled", False)   # a hardware-like recording: skipped
    (root / "notes").mkdir()                  # not a run: ignored
    return root


def test_recordings_give_means_per_backend_view_and_fruit_colour(runs, tmp_path):
    out = tmp_path / "seg.json"
    res = EvalRecordings(out, runs, ["label", "color_depth", "segnet"])
    d = json.loads(out.read_text())
    assert d["_meta"]["runs"] == ["run_green", "run_red"] and d["_meta"]["views"] == 2
    for b in ("label", "color_depth", "segnet"):
        assert set(d[b]["mean"]) == {"fruit_iou", "leaf_iou", "branch_iou"}
        assert set(d[b]["views"]) == {"run_green/view0", "run_red/view0"}
        assert isinstance(d[b]["phantom_fruits_per_view"], float)
        assert set(d[b]["per_fruit_color"]) == {"red", "green"}
        for row in d[b]["views"].values():
            assert all(0 <= r["confidence"] <= 1 for r in row["instance_confidences"])
    assert d["label"]["mean"] == {"fruit_iou": 1.0, "leaf_iou": 1.0, "branch_iou": 1.0}
    assert d["label"]["phantom_fruits_per_view"] == 0.0
    assert d["label"]["per_fruit_color"]["green"] == {"fruit_iou": 1.0, "views": 1}
    assert d["label"]["views"]["run_red/view0"]["fruit_colors"] == {"red": 1.0}
    # segnet on the scene it was trained for
    assert d["segnet"]["per_fruit_color"]["red"]["fruit_iou"] >= 0.8
    assert res["segnet"]["views_evaluated"] == 2
    pictures = sorted(p.name for p in (tmp_path / "seg_views").iterdir())
    assert pictures == ["run_green_view0.png", "run_red_view0.png"]


def test_bad_recordings_folder_is_one_line_and_writes_nothing(runs, tmp_path):
    out = tmp_path / "seg.json"
    with pytest.raises(InputError, match="no such folder"):
        EvalRecordings(out, tmp_path / "nope", ["label"])
    with pytest.raises(InputError, match="no run folder with a labelled recording"):
        EvalRecordings(out, runs / "run_unlabelled", ["label"])
    assert not out.exists() and not list(tmp_path.iterdir())
    main = runpy.run_path(str(REPO_ROOT / "scripts" / "eval_segmentation.py"),
                          run_name="eval_segmentation")["main"]
    with pytest.raises(SystemExit) as e:
        main(["--out", str(out), "--recordings", str(runs), "--backends", "label,magic"])
    assert e.value.code == 2
