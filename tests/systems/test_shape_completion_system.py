import dataclasses as dc

import numpy as np
import pytest
import torch
from pydrake.common.value import AbstractValue

from lmap_drake.scenario import ShapeConfig
from lmap_drake.shape.benchmark import MakeSyntheticCase
from lmap_drake.shape.deepsdf import MissingWeightsError
from lmap_drake.systems.shape_completion import ShapeCompletion
from lmap_drake.types import SceneEstimate, SemanticScene


def test_system_outputs_scene_estimate():
    torch.set_num_threads(1)
    case = MakeSyntheticCase(2, occluded=True)
    sys = ShapeCompletion(dc.replace(ShapeConfig(), iterations=60))
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
