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
    assert res["_meta"]["camera"] == "l515"          # the default, noisy camera
    for backend in ("segnet", "color_depth", "label"):
        mean = res[backend]["mean"]
        assert set(mean) == {"fruit_iou", "leaf_iou", "branch_iou"}
        assert res[backend]["scenarios"]["Defaults"]["fruit_color"] == "red"
    assert res["label"]["mean"]["fruit_iou"] == 1.0
    # fruit instances with the truth of their pixels: the labels have no phantom
    rows = res["label"]["scenarios"]["Defaults"]["fruit_instances"]
    assert len(rows) >= 1 and all(r["fruit"] == 1.0 for r in rows)
    assert res["label"]["instances"] == {"fruit_instances": len(rows), "phantoms": 0}
    assert res["segnet"]["mean"]["fruit_iou"] >= 0.9
    assert res["segnet"]["mean"]["leaf_iou"] >= 0.9
    assert res["segnet"]["mean_non_green"]["fruit_n"] == 1
