import numpy as np
import pytest

from lmap_drake.deformation import (
    BuildGraspGraph, BuildLeafGraph, DeformationError, HandleGrid)
from lmap_drake.deformation.graph import FIXED, FREE, HANDLE, DistanceToLine
from lmap_drake.deformation.synthetic import OvateLeaf
from lmap_drake.deformation.config import DeformationConfig

# Gripper approaching the leaf tip along -x, closing along z (leaf normal).
R_TIP = np.column_stack([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])


@pytest.fixture(scope="module")
def plant():
    return OvateLeaf(spacing=0.0015)


def tip(leaf):
    return leaf[np.argmax(leaf[:, 0] - 5 * np.abs(leaf[:, 1]))] - [0.01, 0, 0]


def test_leaf_graph_nodes_edges_and_weights(plant):
    cfg = DeformationConfig()
    leaf, branch = plant
    g = BuildLeafGraph(leaf, branch, cfg)
    assert 150 < g.num_leaf < 400 and g.num_fixed > 0
    # Voxel nodes: one per occupied 5 mm voxel, each the mean of its points.
    assert g.num_leaf == len(np.unique(np.floor(leaf / 0.005), axis=0))
    assert np.allclose(g.nodes_W[0], leaf[g.point_node == 0].mean(axis=0))
    # Fixed nodes are branch nodes within 5 cm of the leaf.
    d = np.linalg.norm(g.nodes_W[g.num_leaf:, None] - g.nodes_W[None, :g.num_leaf], axis=2)
    assert d.min(axis=1).max() <= cfg.fixed_branch_distance
    # Midrib: the PCA line of this leaf is its x axis (y = 0 plane).
    assert np.allclose(np.abs(g.axis_W), [1, 0, 0], atol=0.1)
    assert np.array_equal(g.vein, DistanceToLine(g.nodes_W[:g.num_leaf], g.centre_W, g.axis_W)
                          <= cfg.vein_distance)
    assert 0 < g.vein.sum() < g.num_leaf
    ll = (g.edges < g.num_leaf).all(axis=1)
    n_vein = g.vein[g.edges[ll, 0]].astype(int) + g.vein[g.edges[ll, 1]]
    assert np.array_equal(g.weights[ll], np.array([1.0, 2.0, 3.0])[n_vein])
    assert set(np.unique(n_vein)) == {0, 1, 2}
    e_len = np.linalg.norm(g.nodes_W[g.edges[ll, 0]] - g.nodes_W[g.edges[ll, 1]], axis=1)
    assert e_len.max() <= cfg.edge_radius
    lb = (g.edges[:, 0] < g.num_leaf) & (g.edges[:, 1] >= g.num_leaf)
    assert lb.any() and np.all(g.weights[lb] == cfg.leaf_branch_weight)


def test_handle_grid_lies_in_pads_plane():
    p = np.array([0.1, 0.2, 0.3])
    h = HandleGrid(p, R_TIP, 5, 0.025)
    assert h.shape == (25, 3)
    local = (h - p) @ R_TIP                       # p_GH in the gripper frame
    assert np.allclose(local[:, 1], 0.0)          # no offset along the closing axis y
    assert np.allclose(local.mean(axis=0), 0.0)   # centred on the grasp point
    assert np.isclose(np.ptp(local[:, 0]), 0.025) and np.isclose(np.ptp(local[:, 2]), 0.025)
    assert len(np.unique(np.round(local[:, [0, 2]], 9), axis=0)) == 25


def test_grasp_graph_orders_and_connects(plant):
    cfg = DeformationConfig()
    leaf, branch = plant
    lg = BuildLeafGraph(leaf, branch, cfg)
    g = BuildGraspGraph(lg, tip(leaf), R_TIP, cfg)
    assert np.array_equal(g.kind, np.r_[np.full(g.num_free, FREE), np.full(g.num_fixed, FIXED),
                                        np.full(g.num_handle, HANDLE)])
    assert g.num_handle == 25 and not g.handle_fallback and g.num_dropped == 0
    handle_edges = (g.kind[g.edges] == HANDLE).sum(axis=1) == 1
    assert handle_edges.sum() > 10
    assert np.allclose(g.nodes_W[:g.num_free], lg.nodes_W[g.base_index[:g.num_free]])


def test_nodes_without_constraint_path_are_dropped(plant):
    cfg = DeformationConfig()
    leaf, branch = plant
    # A detached leaf fragment 10 cm away from everything.
    fragment = leaf[leaf[:, 0] > 0.1] + [0.0, 0.2, 0.0]
    lg = BuildLeafGraph(np.vstack([leaf, fragment]), branch, cfg)
    g = BuildGraspGraph(lg, tip(leaf), R_TIP, cfg)
    fragment_nodes = np.flatnonzero(lg.nodes_W[:lg.num_leaf, 1] > 0.1)
    assert g.num_dropped == len(fragment_nodes) > 0
    assert not np.isin(fragment_nodes, g.base_index).any()
    assert g.nodes_W[:, 1].max() < 0.1


def test_handle_fallback_to_nearest_nodes(plant):
    cfg = DeformationConfig()
    leaf, branch = plant
    lg = BuildLeafGraph(leaf, branch, cfg)
    p = tip(leaf) + [0, 0, 0.012]                 # handle parallel to the leaf, 12 mm above
    g = BuildGraspGraph(lg, p, R_TIP, cfg)
    assert g.handle_fallback
    hl = ((g.kind[g.edges] == HANDLE).sum(axis=1) == 1)
    assert hl.sum() == 25 * cfg.handle_fallback_neighbors


def test_errors(plant):
    cfg = DeformationConfig()
    leaf, branch = plant
    with pytest.raises(DeformationError, match="leaf"):
        BuildLeafGraph(np.zeros((0, 3)), branch, cfg)
    with pytest.raises(DeformationError, match="no branch points"):
        BuildLeafGraph(leaf, np.zeros((0, 3)), cfg)
    with pytest.raises(DeformationError, match="fixed node"):
        BuildLeafGraph(leaf, branch + [0.0, 0.0, 1.0], cfg)
    with pytest.raises(DeformationError, match="not attached"):
        BuildLeafGraph(leaf, branch - [0.03, 0.0, 0.0], cfg)
    lg = BuildLeafGraph(leaf, branch, cfg)
    with pytest.raises(DeformationError, match="max_grasp_distance"):
        BuildGraspGraph(lg, tip(leaf) + [0.0, 0.0, 0.05], R_TIP, cfg)
    # A grasped piece with no path to the branch.
    far = leaf[leaf[:, 0] > 0.1] + [0.0, 0.2, 0.0]
    lg2 = BuildLeafGraph(np.vstack([leaf, far]), branch, cfg)
    with pytest.raises(DeformationError, match="no path to a fixed"):
        BuildGraspGraph(lg2, far[np.argmax(far[:, 0])] - [0.01, 0, 0], R_TIP, cfg)
