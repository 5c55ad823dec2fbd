"""scripts/eval_segmentation.py writes per-backend, per-scenario IoU JSON."""
import json
import runpy
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def test_eval_segmentation_writes_means(tmp_path):
    mod = runpy.run_path(str(REPO / "scripts" / "eval_segmentation.py"), run_name="eval_seg")
    out = tmp_path / "seg.json"
    assert mod["main"](["--out", str(out), "--scenario_file", str(REPO / "diagrams/default.yaml"),
                        "--scenario_names", "Defaults"]) == 0
    res = json.loads(out.read_text())
    for backend in ("color_depth", "label"):
        mean = res[backend]["mean"]
        assert set(mean) == {"fruit_iou", "leaf_iou", "branch_iou"}
        assert res[backend]["scenarios"]["Defaults"]["fruit_color"] == "red"
    assert res["label"]["mean"]["fruit_iou"] == 1.0
    assert res["color_depth"]["mean"]["fruit_iou"] >= 0.9
    assert res["color_depth"]["mean"]["leaf_iou"] >= 0.8
