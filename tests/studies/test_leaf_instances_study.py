"""The leaf-instance study on a view file made here (two blades touching
at one depth, one blade far from them): JSON keys, before and after."""
import json

import numpy as np

from lmap_drake.labels import LEAF, EncodeLabel
from lmap_drake.studies.leaf_instances import EvalLeafInstances, LoadView


def _View(path):
    V, U = np.mgrid[0:240, 0:320]
    a = ((U - 90) / 60.0) ** 2 + ((V - 80) / 25.0) ** 2 <= 1
    b = (((U - 190) / 45.0) ** 2 + ((V - 80) / 25.0) ** 2 <= 1) & ~a
    c = ((U - 160) / 50.0) ** 2 + ((V - 190) / 22.0) ** 2 <= 1
    label = np.zeros(U.shape, np.int16)
    depth = np.full(U.shape, np.inf, np.float32)
    for k, m in enumerate((a, b, c)):
        label[m] = EncodeLabel(LEAF, k)
        depth[m] = 0.5
    rgb = np.zeros(U.shape + (3,), np.uint8)
    np.savez_compressed(path, rgb=rgb, depth=depth, label=label,
                        K=np.array([320, 240, 300.0, 300.0, 160.0, 120.0]))


def test_study_scores_views_before_and_after(tmp_path):
    view = tmp_path / "two_touching.npz"
    _View(view)
    assert LoadView(view)["K"].fx == 300.0
    after = EvalLeafInstances(tmp_path / "after.json", [view], ["truth"], log=lambda s: None)
    before = EvalLeafInstances(tmp_path / "before.json", [view], ["truth"], baseline=True,
                               log=lambda s: None)
    saved = json.loads((tmp_path / "after.json").read_text())
    assert saved["truth"]["image"] == after["truth"]["image"]
    assert set(saved["truth"]) == {"views", "image", "points", "points_kept"}
    assert after["truth"]["image"]["matched_fraction"] == 1.0
    assert after["truth"]["image"]["merges_per_view"] == 0.0
    assert before["truth"]["image"]["merges_per_view"] == 1.0        # a and b as one
    assert before["truth"]["image"]["matched_fraction"] < 1.0
    assert not list(tmp_path.glob("*.partial"))
