"""lmap_drake.studies.segmentation on recorded runs (``scripts/eval_segmentation.py
--recordings DIR``): every labelled DIR/*/recording/, JSON per backend, view
and fruit colour, a picture per view; bad folders fail in one line."""
import json
import runpy

import pytest

from lmap_drake.errors import InputError
from lmap_drake.paths import REPO_ROOT
from lmap_drake.studies.segmentation import EvalRecordings
from recorded_views import RecordView


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    RecordView(root / "run_red", True)
    RecordView(root / "run_green", True, "0.15, 0.45, 0.08")
    RecordView(root / "run_unlabelled", False)   # a hardware-like recording: skipped
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
            if b == "color_depth":     # no score model: none (JSON null, never NaN)
                assert all(r["confidence"] is None for r in row["instance_confidences"])
            else:
                assert all(0 <= r["confidence"] <= 1 for r in row["instance_confidences"])
    assert d["label"]["mean"] == {"fruit_iou": 1.0, "leaf_iou": 1.0, "branch_iou": 1.0}
    assert d["label"]["phantom_fruits_per_view"] == 0.0
    # the label backend's leaf instances are the true leaves (one leaf per view)
    li = d["label"]["leaf_instances"]
    assert (li["matched_fraction"], li["mean_best_iou"], li["leaves"]) == (1.0, 1.0, 2)
    assert li["merges_per_view"] == li["splits_per_view"] == 0.0
    # one leaf per view: no seam to find; backends without a band give none
    assert d["label"]["leaf_boundary"] == {"precision": None, "recall": None, "views": 2}
    assert d["color_depth"]["leaf_boundary"] is None
    assert d["label"]["per_fruit_color"]["green"] == {"fruit_iou": 1.0, "fruit_recall": 1.0,
                                                      "views": 1}
    assert d["label"]["views"]["run_red/view0"]["fruit_colors"] == {
        "red": {"fruit_iou": 1.0, "fruit_recall": 1.0}}
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
