import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lmap_drake.deformation import (
    BuildLeafGraph, DenseInterpolator, MakeActions, PredictDeformations)
from lmap_drake.deformation.graph import Voxelize
from lmap_drake.deformation.synthetic import OvateLeaf
from lmap_drake.deformation.config import DeformationConfig

R_TIP = np.column_stack([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])


@pytest.fixture(scope="module")
def plant():
    return OvateLeaf(spacing=0.0015)


def test_rigid_node_motion_moves_points_rigidly(plant):
    leaf, _ = plant
    nodes, _ = Voxelize(leaf, 0.005)
    interp = DenseInterpolator(leaf, nodes, np.ones(len(leaf), bool), 8, 0.05, 0.005)
    assert interp.moved.all()
    assert np.allclose(interp.W.sum(axis=1), 1.0)
    R = Rotation.from_rotvec([0.3, -0.5, 0.2]).as_matrix()
    t = np.array([0.02, 0.0, -0.01])
    deformed = np.stack([nodes, nodes @ R.T + t])
    rots = np.stack([np.broadcast_to(np.eye(3), (len(nodes), 3, 3)),
                     np.broadcast_to(R, (len(nodes), 3, 3))])
    out = interp.Apply(nodes, deformed, rots)
    assert np.allclose(out[0], leaf, atol=1e-12)
    assert np.allclose(out[1], leaf @ R.T + t, atol=1e-12)


def test_points_of_dropped_nodes_stay(plant):
    leaf, _ = plant
    nodes, point_node = Voxelize(leaf, 0.005)
    movable = nodes[point_node, 0] < 0.06
    interp = DenseInterpolator(leaf, nodes, movable, 8, 0.05, 0.005)
    out = interp.Apply(nodes, nodes[None] + [0.0, 0.0, 0.05],
                       np.broadcast_to(np.eye(3), (1, len(nodes), 3, 3)))
    assert np.array_equal(interp.moved, movable)
    assert np.allclose(out[0, ~movable], leaf[~movable])
    assert np.allclose(out[0, movable], leaf[movable] + [0.0, 0.0, 0.05])


def test_dense_prediction_follows_the_graph(plant):
    leaf, branch = plant
    cfg = DeformationConfig(max_iterations=100)
    p = leaf[np.argmax(leaf[:, 0] - 5 * np.abs(leaf[:, 1]))] - [0.01, 0, 0]
    [pred] = PredictDeformations(leaf, branch, MakeActions([(p, R_TIP)], [[0, 0, 1.0]], [0.05]),
                                 cfg)
    dense = pred.leaf_points_W
    assert dense.shape == leaf.shape and np.isfinite(dense).all()
    near_grasp = np.linalg.norm(leaf - p, axis=1) < 0.005
    assert np.allclose((dense - leaf)[near_grasp].mean(axis=0), [0, 0, 0.05], atol=0.005)
    # Each dense point stays within a voxel or so of its nearest deformed node.
    lg = BuildLeafGraph(leaf, branch, cfg)
    rest_d = np.linalg.norm(leaf - lg.nodes_W[lg.point_node], axis=1)
    from scipy.spatial import cKDTree
    d, _ = cKDTree(pred.deformed_nodes_W[pred.node_kind != 2]).query(dense)
    assert d.max() < rest_d.max() + 0.004
