"""lmap_drake.studies.segmentation (scripts/eval_segmentation.py) writes
per-backend, per-scenario IoU JSON."""
import json

from lmap_drake.paths import REPO_ROOT as REPO
from lmap_drake.studies.segmentation import EvalSegmentation


def test_eval_segmentation_writes_means(tmp_path):
    out = tmp_path / "seg.json"
    EvalSegmentation(out=str(out), scenario_file=REPO / "diagrams/default.yaml",
                     scenario_names=["Defaults"])
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
