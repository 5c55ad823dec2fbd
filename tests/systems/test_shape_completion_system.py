import dataclasses as dc

import numpy as np
import pytest
import torch
from pydrake.common.value import AbstractValue

from lmap_drake.shape.config import ShapeConfig, SscConfig
from lmap_drake.studies.shape_benchmark import MakeSyntheticCase
from lmap_drake.shape.deepsdf import MissingWeightsError
from lmap_drake.systems.shape_completion import ShapeCompletion
from lmap_drake.types import SceneEstimate, SemanticScene


def test_system_outputs_scene_estimate():
    torch.set_num_threads(1)
    case = MakeSyntheticCase(2, occluded=True)
    sys = ShapeCompletion(ShapeConfig(ssc=SscConfig(iterations=60)))
    ctx = sys.CreateDefaultContext()
    sys.GetInputPort("semantic_scene").FixValue(ctx, AbstractValue.Make(case.semantic))
    est = sys.GetOutputPort("scene_estimate").Eval(ctx)
    assert isinstance(est, SceneEstimate)
    assert est.branch is not None and len(est.branch.samples_W) > 100
    f = est.fruit
    assert f is not None and f.X_WO.shape == (4, 4) and len(f.faces) > 100
    assert np.linalg.norm(f.center_W - case.gt_center_W) < 0.03
    # sdf_W is batched numpy: observed fruit points are near the surface.
    d = f.sdf_W(case.semantic.fruit_points_W)
    assert d.shape == (len(case.semantic.fruit_points_W),) and np.median(np.abs(d)) < 0.005
    # Cached: a second Eval returns the same result without recomputation.
    assert sys.GetOutputPort("scene_estimate").Eval(ctx) is est or \
        sys.GetOutputPort("scene_estimate").Eval(ctx).fruit is f
    # The decoder is an attribute, not state.
    assert ctx.num_abstract_states() == 0 and sys.decoder is not None


def test_empty_scene_gives_no_fruit():
    sys = ShapeCompletion()
    ctx = sys.CreateDefaultContext()
    sys.GetInputPort("semantic_scene").FixValue(ctx, AbstractValue.Make(SemanticScene()))
    est = sys.GetOutputPort("scene_estimate").Eval(ctx)
    assert est.fruit is None and est.branch is None


def test_missing_weights_is_a_clear_error(tmp_path):
    cfg = dc.replace(ShapeConfig(), weights_file=str(tmp_path / "missing.pt"))
    with pytest.raises(MissingWeightsError, match="train_deepsdf"):
        ShapeCompletion(cfg)


def test_a_view_segmented_again_is_not_completed_again(monkeypatch):
    """``plant_estimate`` keeps its last result for a scene of equal
    contents (perception hands a new object for the same view), and
    completes a scene that differs."""
    import lmap_drake.systems.shape_completion as module
    torch.set_num_threads(1)
    calls = []
    real = module.CompletePlant
    monkeypatch.setattr(module, "CompletePlant",
                        lambda *a, **k: calls.append(1) or real(*a, **k))
    sem = MakeSyntheticCase(2, occluded=True).semantic
    sys = ShapeCompletion(ShapeConfig(ssc=SscConfig(iterations=20)))
    ctx = sys.CreateDefaultContext()
    port = sys.GetOutputPort("plant_estimate")
    sys.GetInputPort("semantic_scene").FixValue(ctx, AbstractValue.Make(sem))
    first = port.Eval(ctx)
    copy = dc.replace(sem, fruit_points_W=sem.fruit_points_W.copy())
    assert copy is not sem and copy.Fingerprint() == sem.Fingerprint()
    sys.GetInputPort("semantic_scene").FixValue(ctx, AbstractValue.Make(copy))
    assert port.Eval(ctx) is first and len(calls) == 1
    moved = dc.replace(sem, fruit_points_W=sem.fruit_points_W + [0.0, 0.0, 0.001])
    assert moved.Fingerprint() != sem.Fingerprint()
    sys.GetInputPort("semantic_scene").FixValue(ctx, AbstractValue.Make(moved))
    assert port.Eval(ctx) is not first and len(calls) == 2


def test_the_smallest_fruit_instance_completed_is_the_configured_one():
    """``shape.min_fruit_points`` reaches ``CompletePlant``: a 25-point fruit
    instance (a fruit about 6 % in view) is completed at 20, not at 30."""
    torch.set_num_threads(1)
    sem = MakeSyntheticCase(2, occluded=True).semantic
    rng = np.random.default_rng(0)
    keep = rng.choice(len(sem.fruit_points_W), 25, replace=False)
    small = dc.replace(sem, fruit_points_W=sem.fruit_points_W[keep],
                       fruit_instance=np.zeros(25, np.int64))
    counts = {}
    for n in (20, 30):
        sys = ShapeCompletion(ShapeConfig(ssc=SscConfig(iterations=5), min_fruit_points=n))
        ctx = sys.CreateDefaultContext()
        sys.GetInputPort("semantic_scene").FixValue(ctx, AbstractValue.Make(small))
        counts[n] = len(sys.GetOutputPort("plant_estimate").Eval(ctx).fruits)
    assert counts == {20: 1, 30: 0}
