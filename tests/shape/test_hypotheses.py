"""lmap_drake.shape.hypotheses: the set of plausible fruit shapes from one
partial view, fitted in one batched optimisation (a known template shape
seen from one side: its volume lies in the set's interval; with its whole
front seen, the smaller shapes drop out)."""
import json

import numpy as np
import pytest
import torch

from lmap_drake.episode.records import HypothesesRecord, PlanRecord
from lmap_drake.shape.config import ShapeConfig, SscConfig
from lmap_drake.shape.deepsdf import LoadDecoder
from lmap_drake.shape.free_space import FreeSpacePoints
from lmap_drake.shape.hypotheses import FitHypotheses, Starts
from lmap_drake.shape.metrics import MeshVolume
from lmap_drake.shape.ssc import MakeFruitEstimate, OptimizeShape
from lmap_drake.types import FruitEstimate, SceneEstimate, SemanticScene

from tests.shape.test_ssc import CAM, _gt, _visible_points


@pytest.fixture(scope="module")
def template():
    torch.set_num_threads(1)
    dec, mean, extra = LoadDecoder(ShapeConfig().weights_file)
    return dec, mean, extra["train_latents"].numpy()


P = SscConfig(iterations=150, num_hypotheses=6, hypothesis_iterations=100)


def _set(dec, mean, obs):
    free = FreeSpacePoints(CAM, obs, obs, 0.003)
    est = OptimizeShape(dec, mean, obs, CAM, [(free, 1.0)], None, P)
    return est, FitHypotheses(dec, mean, obs, CAM, [(free, 1.0)], P, est)


def test_the_set_covers_the_true_volume_and_more_of_the_front_rules_out_smaller_shapes(template):
    """The template's mean shape 15 % larger than the start, half hidden;
    then its whole front in view. Both sets hold the true volume; with the
    whole front seen the smaller shapes no longer fit, so the interval's
    lower end rises. Its width need not shrink: the back is still unseen,
    and deeper shapes still fit (over optimiser seeds 0-5, 2026-11-29: the
    lower end rose 1.32-1.52x, the width changed 0.68-1.06x; an earlier
    bound on the width held on one seed and one CPU only)."""
    dec, mean, lat = template
    gt, _ = _gt(dec, mean, s=1.15)
    v_true = abs(MeshVolume(gt.vertices_W, gt.faces)) * 1e6
    est, part = _set(dec, mean, _visible_points(gt, keep_right_half=True, n=400))
    lo, hi = part.volume_interval_cm3
    assert lo <= v_true <= hi, (lo, v_true, hi)
    assert part.num_fitted == 6 and 1 <= len(part.volume_cm3) <= 6
    # hypothesis 0 is the estimate itself
    assert np.allclose(part.X_WO[0], est.X_WO) and part.vertices_W[0] is est.vertices_W
    assert part.axis_spread_deg >= 0
    assert np.all(part.center_interval_W[0] <= part.center_interval_W[1])
    _, whole = _set(dec, mean, _visible_points(gt, n=1500))
    lo2, hi2 = whole.volume_interval_cm3
    assert lo2 <= v_true <= hi2, (lo2, v_true, hi2)
    assert lo2 > 1.2 * lo, ((lo, hi), (lo2, hi2))


def test_starts_are_diverse_in_scale_axis_and_latent(template):
    dec, mean, lat = template
    gt, _ = _gt(dec, lat[3])
    obs = _visible_points(gt, n=300)
    start = MakeFruitEstimate(dec, lat[2], 1.1, np.eye(3), obs.mean(0), 0.004)
    z, s, R, t = Starts(dec, mean, obs, CAM, SscConfig(num_hypotheses=8), start)
    assert len(s) == 8 and s[0] == pytest.approx(1.1)
    assert s[1:].max() / s[1:].min() == pytest.approx(2.0, rel=1e-6)     # 0.7 .. 1.4
    tilts = np.degrees(np.arccos(np.clip(R[1:, 2, 2], -1, 1)))     # about the estimate's
    assert tilts.max() == pytest.approx(15.0, abs=1e-6) and tilts.min() == 0.0
    assert len(np.unique(np.round(z[1:], 5), axis=0)) == 3      # the fit's, +-50 % of its offset
    # a larger start sits further from the camera
    d = np.linalg.norm(t[1:] - CAM, axis=1)
    assert np.all(np.diff(d) > 0)


def test_the_set_is_written_in_plan_json_form(template):
    dec, mean, lat = template
    gt, _ = _gt(dec, lat[3])
    obs = _visible_points(gt, keep_right_half=True, n=300)
    est = OptimizeShape(dec, mean, obs, CAM, [], None, SscConfig(iterations=20))
    est.hypotheses = FitHypotheses(dec, mean, obs, CAM, [], SscConfig(
        num_hypotheses=3, hypothesis_iterations=5), est)
    scene = SceneEstimate(SemanticScene(), fruit=est)
    rec = json.loads(json.dumps(HypothesesRecord(scene)))
    assert rec["num_fitted"] == 3 and rec["num_kept"] == len(rec["volume_cm3"]) >= 1
    lo, hi = rec["volume_interval_cm3"]
    assert lo <= min(rec["volume_cm3"]) + 0.01 and hi >= max(rec["volume_cm3"]) - 0.01
    assert np.asarray(rec["X_WO"]).shape == (rec["num_kept"], 4, 4)
    assert PlanRecord(None, None, scene)["shape_hypotheses"] == HypothesesRecord(scene)
    assert HypothesesRecord(SceneEstimate(SemanticScene())) is None
    assert HypothesesRecord(SceneEstimate(SemanticScene(), fruit=FruitEstimate(
        *[np.zeros(3)] * 6))) is None
