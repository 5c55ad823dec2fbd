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


def test_view_rows_score_the_leaf_boundary_band_against_the_true_seams():
    import numpy as np
    from lmap_drake.labels import LEAF, EncodeLabel
    from lmap_drake.perception.segmentation import LabelSegmenter, Segmentation, TruthClassMap
    from lmap_drake.studies.segmentation import Summary, ViewRow
    label = np.zeros((40, 60), np.int32)
    label[5:35, 5:30] = EncodeLabel(LEAF, 0)
    label[5:35, 30:55] = EncodeLabel(LEAF, 1)         # flush against leaf 0
    rgb = np.full((40, 60, 3), 90, np.uint8)
    truth = TruthClassMap(label)
    exact = LabelSegmenter().Segment(None, None, label)
    row = ViewRow(exact, truth, label, rgb)
    assert row["leaf_boundary"]["true_px"] == row["leaf_boundary"]["hit_px"] > 0
    half = exact.leaf_boundary.copy()
    half[20:] = False                                 # the band on the upper half only
    rows = [row, ViewRow(Segmentation(exact.class_map, exact.instance_map, [], {}, half),
                         truth, label, rgb)]
    for r in rows:
        r["fruit_color"] = None                       # as the evaluation sets it per scene
    b = Summary(rows)["leaf_boundary"]
    assert b["precision"] == 1.0 and 0.7 < b["recall"] < 0.8 and b["views"] == 2
    none = ViewRow(Segmentation(exact.class_map, exact.instance_map), truth, label, rgb)
    none["fruit_color"] = None
    assert "leaf_boundary" not in none and Summary([none])["leaf_boundary"] is None


def test_pooled_iou_sums_the_pixels_of_every_view_where_the_mean_averages_views():
    import numpy as np
    from lmap_drake.labels import FRUIT, LEAF, EncodeLabel
    from lmap_drake.perception.segmentation import LabelSegmenter, Segmentation, TruthClassMap
    from lmap_drake.studies.segmentation import Summary, ViewRow
    rgb = np.full((40, 60, 3), 90, np.uint8)
    with_fruit = np.zeros((40, 60), np.int32)
    with_fruit[5:35, 5:30] = EncodeLabel(LEAF, 0)
    with_fruit[10:30, 35:55] = EncodeLabel(FRUIT, 0)      # 400 fruit pixels
    fruitless = np.zeros((40, 60), np.int32)
    fruitless[5:35, 5:30] = EncodeLabel(LEAF, 0)
    rows = []
    for label in (with_fruit, fruitless):
        exact = LabelSegmenter().Segment(None, None, label)
        cls = exact.class_map.copy()
        if label is fruitless:
            cls[0:2, 0:2] = FRUIT                            # 4 stray pixels called fruit
        r = ViewRow(Segmentation(cls, exact.instance_map), TruthClassMap(label), label, rgb)
        r["fruit_color"] = None
        rows.append(r)
    assert [r["fruit_iou"] for r in rows] == [1.0, 0.0]
    s = Summary(rows)
    assert s["mean"]["fruit_iou"] == 0.5
    assert s["pooled"]["fruit_iou"] == round(400 / 404, 4)
    assert s["pooled"]["leaf_iou"] == 1.0 and s["pooled"]["branch_iou"] is None
