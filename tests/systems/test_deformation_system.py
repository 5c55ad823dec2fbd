import numpy as np
import pytest
from pydrake.systems.framework import DiagramBuilder

from lmap_drake.deformation import DeformationError, MakeActions, PredictDeformations
from lmap_drake.deformation.synthetic import OvateLeaf
from lmap_drake.deformation.config import DeformationConfig
from lmap_drake.systems.deformation import DeformationPrediction
from lmap_drake.types import BranchEstimate, SceneEstimate, SemanticScene

R_TIP = np.column_stack([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])
CFG = DeformationConfig(max_iterations=60)


@pytest.fixture(scope="module")
def plant():
    return OvateLeaf(spacing=0.0015, p_WL=[0.5, -0.1, 0.35])


def actions_for(leaf):
    p = leaf[np.argmax(leaf[:, 0] - 5 * np.abs(leaf[:, 1 ] + 0.1))] - [0.01, 0, 0]
    q = leaf[np.argmin(np.abs(leaf[:, 0] - 0.58) + np.abs(leaf[:, 1] + 0.085))]
    R_side = np.column_stack([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    a = MakeActions([(p, R_TIP)], [[0, 0, 1.0], [1.0, 0, 0]], [0.02, 0.06])
    b = MakeActions([(q, R_side)], [[0, 1.0, 0]], [0.04])
    return [a[0], b[0], a[3], a[1], a[2]]           # grasps interleaved


def test_system_ports_and_predictions(plant):
    leaf, branch = plant
    system = DeformationPrediction(CFG)
    builder = DiagramBuilder()
    builder.AddSystem(system)
    builder.ExportInput(system.get_input_port(0), "scene_estimate")
    builder.ExportInput(system.get_input_port(1), "actions")
    builder.ExportOutput(system.get_output_port(0), "predictions")
    diagram = builder.Build()
    ctx = diagram.CreateDefaultContext()
    # Branch split between the segmented points and the completed samples.
    scene = SceneEstimate(
        semantic=SemanticScene(leaf_points_W=leaf, branch_points_W=branch[: len(branch) // 2]),
        branch=BranchEstimate(vertices_W=np.zeros((0, 3)), faces=np.zeros((0, 3), int),
                              samples_W=branch[len(branch) // 2:], axis_W=np.array([0, 0, 1.0])))
    actions = actions_for(leaf)
    diagram.GetInputPort("scene_estimate").FixValue(ctx, scene)
    diagram.GetInputPort("actions").FixValue(ctx, actions)
    preds = diagram.GetOutputPort("predictions").Eval(ctx)
    assert [p.action for p in preds] == actions
    ref = PredictDeformations(leaf, branch, actions, CFG)
    for p, r in zip(preds, ref):
        assert np.isclose(p.energy, r.energy, rtol=1e-9)
        assert p.leaf_points_W.shape == leaf.shape
        assert np.allclose(p.deformed_nodes_W[p.node_kind == 2] - p.nodes_W[p.node_kind == 2],
                           p.action.dp_W)
    assert preds[3].energy > preds[0].energy          # 6 cm up costs more than 2 cm up
    assert len(system._grasps) == 2                   # one factorisation per grasp


def test_system_rejects_unusable_scene(plant):
    leaf, branch = plant
    system = DeformationPrediction(CFG)
    ctx = system.CreateDefaultContext()
    system.get_input_port(0).FixValue(ctx, SceneEstimate(
        semantic=SemanticScene(leaf_points_W=leaf, branch_points_W=np.zeros((0, 3)))))
    system.get_input_port(1).FixValue(ctx, actions_for(leaf))
    with pytest.raises(DeformationError, match="no branch"):
        system.get_output_port(0).Eval(ctx)
    system.get_input_port(1).FixValue(ctx, [])
    assert system.get_output_port(0).Eval(ctx) == []
