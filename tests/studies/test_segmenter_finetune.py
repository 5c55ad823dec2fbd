"""``lmap-drake train-segmenter`` on two recordings made here, annotated
with COCO and LabelMe polygons drawn from the renderer's labels, mixed with
simulated samples: new weights written (loadable), held-out IoU printed;
bad annotations fail in one line (exit code 2)."""
import json

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from lmap_drake.cli import main as cli_main
from lmap_drake.labels import BRANCH, FRUIT, LEAF, DecodeLabels, LeafBoundaryMask
from lmap_drake.perception.annotations import Annotation, LoadCoco, RasterisePolygons
from lmap_drake.perception.points import Intrinsics
from lmap_drake.perception.segnet import LoadSegNet, SegNetInputs
from recorded_views import RecordView

NAMES = {FRUIT: "sweet pepper", LEAF: "leaf", BRANCH: "main stem"}


def _Polygons(label) -> list:
    """(class, exact polygons, hull) per true instance: a rectangle per run
    of its pixels in a row, and the convex hull of its pixels."""
    cls, inst = DecodeLabels(label)
    out = []
    for c in (BRANCH, LEAF, FRUIT):
        for i in np.unique(inst[cls == c]):
            m = (cls == c) & (inst == i)
            if m.sum() < 10:
                continue
            runs = []
            for y in np.nonzero(m.any(1))[0]:
                d = np.diff(np.r_[0, m[y].astype(int), 0])
                for x0, x1 in zip(np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]):
                    runs.append([int(v) for v in (x0, y, x1, y, x1, y + 1, x0, y + 1)])
            ys, xs = np.nonzero(m)
            pts = np.stack([xs + 0.5, ys + 0.5], 1)
            out.append((c, runs, pts[ConvexHull(pts).vertices]))
    return out


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("captures")
    views = {"lab_a": RecordView(root / "lab_a", with_label=False),
             "lab_b": RecordView(root / "lab_b", with_label=False, fruit_rgb="0.9, 0.75, 0.05")}
    coco = {"images": [], "annotations": [], "categories": [
        {"id": k, "name": n} for k, n in NAMES.items()] + [{"id": 9, "name": "pot"}]}
    for k, (run, v) in enumerate(views.items()):
        coco["images"].append({"id": k, "file_name": f"{run}/recording/view0_rgb.png",
                               "width": 320, "height": 240})
        shapes = []
        for c, runs, hull in _Polygons(v.label):
            coco["annotations"].append({"id": len(coco["annotations"]), "image_id": k,
                                        "category_id": c, "segmentation": runs})
            shapes.append({"label": NAMES[c], "points": hull.tolist(), "shape_type": "polygon"})
        (root / run / "recording" / "view0_rgb.json").write_text(json.dumps(
            {"imagePath": "view0_rgb.png", "imageWidth": 320, "imageHeight": 240,
             "shapes": shapes}))
    (root / "coco.json").write_text(json.dumps(coco))
    # simulated samples in make_segnet_data.py's format
    sim = root / "sim"
    sim.mkdir()
    v = RecordView(root / "sim_run", fruit_rgb="0.95, 0.45, 0.05")
    K = Intrinsics(320, 240, 228.4, 228.5, 160.0, 120.0)
    cls, _ = DecodeLabels(v.label)
    np.savez(sim / "000001.npz", inputs=SegNetInputs(v.rgb, v.depth, K, 1.5).astype(np.float16),
             truth=np.where(cls == 4, 0, cls).astype(np.uint8), fruit_kind="orange")
    return root, views


def test_annotations_rasterise_to_the_labels(runs):
    root, views = runs
    ann = LoadCoco(root / "coco.json")["lab_a/recording/view0_rgb.png"]
    truth, _ = DecodeLabels(views["lab_a"].label)
    truth = np.where(truth == 4, 0, truth)       # the robot is not annotated
    y = ann.ClassMap()
    assert y.shape == (240, 320)
    assert np.array_equal(y, truth)              # the pixel runs give back the labels
    square = RasterisePolygons([(LEAF, [np.array([[0, 0], [4, 0], [4, 4], [0, 4.]])])], 6, 6)
    assert square.sum() == LEAF * 16 and square[:4, :4].all()
    # a fruit drawn inside a leaf's outline stays fruit, whatever the order
    shapes = [(FRUIT, [np.array([[1, 1], [3, 1], [3, 3], [1, 3.]])]),
              (LEAF, [np.array([[0, 0], [6, 0], [6, 6], [0, 6.]])])]
    assert (RasterisePolygons(shapes, 6, 6) == FRUIT).sum() == 4
    # one id per annotated leaf (the boundary head's target), none under a fruit
    truth_leaf = np.where(DecodeLabels(views["lab_a"].label)[0] == LEAF, 0, -1)
    assert np.array_equal(ann.LeafIds() >= 0, truth_leaf >= 0)
    two = Annotation("x.png", 12, 8, [(LEAF, [np.array([[0, 0], [6, 0], [6, 8], [0, 8.]])]),
                                      (LEAF, [np.array([[6, 0], [12, 0], [12, 8], [6, 8.]])]),
                                      (FRUIT, [np.array([[1, 1], [3, 1], [3, 3], [1, 3.]])])])
    ids = two.LeafIds()
    assert set(np.unique(ids)) == {-1, 0, 1} and (ids[1:3, 1:3] == -1).all()
    band = LeafBoundaryMask(ids)
    assert band[:, 4:8].all() and not band[:, :4].any() and not band[:, 8:].any()


def test_train_segmenter_writes_weights_and_prints_held_out_iou(runs, tmp_path, capsys):
    root, _ = runs
    out = tmp_path / "segnet_lab.pt"
    rc = cli_main(["train-segmenter", "--recordings", str(root), "--annotations",
                   str(root / "coco.json"), "--sim_data", str(root / "sim"), "--out", str(out),
                   "--steps", "2", "--batch", "2"])
    assert rc == 0
    text = capsys.readouterr().out
    assert "held-out IoU (1 views) before: {'fruit_iou'" in text and "after 2 steps" in text
    net = LoadSegNet(out)
    meta = json.loads(out.with_suffix(".json").read_text())
    assert net.meta["held_out_views"] == ["lab_a/recording/view0_rgb.png"] == meta["held_out_views"]
    assert meta["train_views"] == ["lab_b/recording/view0_rgb.png"] and meta["sim_samples"] == 1
    assert 0.0 <= meta["held_out_iou_after"]["fruit_iou"] <= 1.0
    # the LabelMe files beside the images, without --annotations
    out2 = tmp_path / "segnet_labelme.pt"
    assert cli_main(["train-segmenter", "--recordings", str(root), "--out", str(out2),
                     "--steps", "1", "--batch", "1"]) == 0
    assert json.loads(out2.with_suffix(".json").read_text())["annotations"] == "labelme"


def test_bad_annotations_are_one_line_errors(runs, tmp_path, capsys):
    root, _ = runs
    out = tmp_path / "w.pt"
    rle = tmp_path / "rle.json"
    rle.write_text(json.dumps({"images": [{"id": 0, "file_name": "x.png", "width": 2,
                                           "height": 2}], "categories": [{"id": 1, "name": "leaf"}],
                               "annotations": [{"image_id": 0, "category_id": 1,
                                                "segmentation": {"counts": "x", "size": [2, 2]}}]}))
    elsewhere = tmp_path / "elsewhere.json"
    elsewhere.write_text(json.dumps({"images": [{"id": 0, "file_name": "other/view9_rgb.png",
                                                 "width": 320, "height": 240}],
                                     "categories": [], "annotations": []}))
    for args, msg in ((["--annotations", str(rle)], "run-length mask"),
                      (["--annotations", str(elsewhere)], "not a recorded colour image"),
                      (["--annotations", str(tmp_path / "none.json")], "not found"),
                      (["--sim_fraction", "1.5"], "--sim_fraction must be in")):
        assert cli_main(["train-segmenter", "--recordings", str(root), "--out", str(out),
                         "--steps", "1"] + args) == 2
        err = capsys.readouterr().err.strip()
        assert msg in err and len(err.splitlines()) == 1, err
    assert not out.exists()
