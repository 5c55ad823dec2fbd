"""Embedded deformation graph (paper Sec. III-B), world frame W, metres.

Nodes: leaf points voxelised at ``voxel_size`` (deformable), branch points
voxelised the same way and kept within ``fixed_branch_distance`` of the leaf
(fixed), and a ``handle_grid`` x ``handle_grid`` gripper handle (moved by the
action). Edges connect nodes closer than ``edge_radius``; leaf-to-branch
edges use ``leaf_branch_edge_radius`` and ``leaf_branch_weight``. Leaf-leaf
(and leaf-handle) edges weigh 3 / 2 / 1 (``vein_weights``) for two / one /
no endpoints on the midrib: leaf nodes within ``vein_distance`` of the PCA
centre line of the leaf points. Nodes with no path to a constrained (fixed
or handle) node are dropped.
"""
from __future__ import annotations

import dataclasses as dc

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from lmap_drake.deformation.action import DeformationError
from lmap_drake.deformation.config import DeformationConfig

FREE, FIXED, HANDLE = 0, 1, 2


def Voxelize(points_W: np.ndarray, voxel_size: float) -> tuple[np.ndarray, np.ndarray]:
    """Mean point of every occupied voxel (n, 3) and, per input point, the
    index of its voxel (N,). Voxels are ordered lexicographically."""
    keys = np.floor(points_W / voxel_size).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    centres = np.stack([np.bincount(inverse, points_W[:, k]) for k in range(3)], axis=1)
    return centres / counts[:, None], inverse


def PcaCentreLine(points_W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroid (3,) and unit first principal axis (3,) of ``points_W``."""
    c = points_W.mean(axis=0)
    _, _, vt = np.linalg.svd(points_W - c, full_matrices=False)
    return c, vt[0]


def DistanceToLine(points_W: np.ndarray, c: np.ndarray, axis: np.ndarray) -> np.ndarray:
    d = points_W - c
    return np.linalg.norm(d - np.outer(d @ axis, axis), axis=1)


def HandleGrid(p_WG: np.ndarray, R_WG: np.ndarray, grid: int, size: float) -> np.ndarray:
    """The gripper handle (grid*grid, 3) in W: a square of side ``size`` (m)
    centred on ``p_WG`` in the pads' plane, i.e. spanned by the gripper's x
    (pad width) and z (approach) axes; y (closing direction) is its normal."""
    s = np.linspace(-size / 2, size / 2, grid) if grid > 1 else np.zeros(1)
    sx, sz = np.meshgrid(s, s, indexing="ij")
    p_GH = np.stack([sx.ravel(), np.zeros(sx.size), sz.ravel()], axis=1)
    return np.asarray(p_WG, float) + p_GH @ np.asarray(R_WG, float).T


def MainLeafComponent(leaf_points_W: np.ndarray, config: DeformationConfig) -> np.ndarray:
    """Mask (N,) of the leaf points in the largest connected part of the leaf
    as the graph would connect it (voxels of ``voxel_size``, edges within
    ``edge_radius``): the blade, without specks the segmenter labelled
    leaf elsewhere (near the branch, they would take the virtual petiole
    and leave the blade unattached)."""
    leaf = np.asarray(leaf_points_W, float).reshape(-1, 3)
    if len(leaf) < 2:
        return np.ones(len(leaf), bool)
    nodes, point_node = Voxelize(leaf, config.voxel_size)
    pairs = cKDTree(nodes).query_pairs(config.edge_radius, output_type="ndarray")
    adj = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                     shape=(len(nodes), len(nodes)))
    _, label = connected_components(adj, directed=False)
    main = np.argmax(np.bincount(label, minlength=label.max() + 1))
    return label[point_node] == main


@dc.dataclass
class LeafGraph:
    """The grasp-independent part of the graph. ``nodes_W`` holds the
    ``num_leaf`` leaf nodes first, then the fixed (branch) nodes. ``edges``
    (m, 2) are undirected (i < j) with ``weights`` (m,). ``point_node`` maps
    every dense leaf point to its voxel node."""
    nodes_W: np.ndarray
    num_leaf: int
    vein: np.ndarray
    edges: np.ndarray
    weights: np.ndarray
    leaf_points_W: np.ndarray
    point_node: np.ndarray
    centre_W: np.ndarray
    axis_W: np.ndarray
    leaf_tree: cKDTree = dc.field(repr=False)

    @property
    def num_fixed(self) -> int:
        return len(self.nodes_W) - self.num_leaf


@dc.dataclass
class GraspGraph:
    """The graph for one grasp, restricted to nodes with a path to a
    constrained node. ``nodes_W`` (n, 3) is ordered [free leaf | fixed |
    handle]; ``kind`` (n,) holds FREE / FIXED / HANDLE; ``base_index`` maps
    the free and fixed nodes to ``LeafGraph.nodes_W`` (-1 for handle nodes).
    ``handle_fallback`` is True when no leaf node lay within ``edge_radius``
    of the handle and the handle was tied to its nearest leaf nodes."""
    nodes_W: np.ndarray
    kind: np.ndarray
    edges: np.ndarray
    weights: np.ndarray
    base_index: np.ndarray
    num_free: int
    num_fixed: int
    num_handle: int
    handle_fallback: bool
    num_dropped: int

    @property
    def num_constrained(self) -> int:
        return self.num_fixed + self.num_handle


def _pairs(tree_a: cKDTree, tree_b: cKDTree, r: float) -> np.ndarray:
    """(k, 2) index pairs (a, b) with |a - b| <= r."""
    m = tree_a.sparse_distance_matrix(tree_b, r, output_type="ndarray")
    return np.stack([m["i"], m["j"]], axis=1).astype(np.int64)


def BuildLeafGraph(leaf_points_W: np.ndarray, branch_points_W: np.ndarray,
                   config: DeformationConfig) -> LeafGraph:
    """Voxelises leaf and branch points (W, m) and connects them.
    Raises DeformationError for an empty leaf, no branch point near the
    leaf, or a leaf with no edge to any fixed node."""
    leaf = np.asarray(leaf_points_W, dtype=float).reshape(-1, 3)
    branch = np.asarray(branch_points_W, dtype=float).reshape(-1, 3)
    leaf = leaf[np.isfinite(leaf).all(axis=1)]
    branch = branch[np.isfinite(branch).all(axis=1)]
    if len(leaf) < 3:
        raise DeformationError(f"leaf has {len(leaf)} points; the deformation graph needs a leaf")
    if len(branch) == 0:
        raise DeformationError("no branch points: the leaf has no fixed node to hang from")
    leaf_nodes, point_node = Voxelize(leaf, config.voxel_size)
    branch_nodes, _ = Voxelize(branch, config.voxel_size)
    leaf_tree = cKDTree(leaf_nodes)
    d_branch, _ = leaf_tree.query(branch_nodes, k=1,
                                  distance_upper_bound=config.fixed_branch_distance)
    fixed = branch_nodes[np.isfinite(d_branch)]
    if len(fixed) == 0:
        raise DeformationError(
            f"no branch point within fixed_branch_distance={config.fixed_branch_distance} m "
            f"of the leaf: no fixed node")
    n_leaf = len(leaf_nodes)
    fixed_tree = cKDTree(fixed)
    centre, axis = PcaCentreLine(leaf)
    vein = DistanceToLine(leaf_nodes, centre, axis) <= config.vein_distance
    w_two, w_one, w_none = config.vein_weights

    ll = leaf_tree.query_pairs(config.edge_radius, output_type="ndarray").astype(np.int64)
    n_vein = vein[ll[:, 0]].astype(int) + vein[ll[:, 1]]
    w_ll = np.choose(n_vein, [w_none, w_one, w_two])
    lb = _pairs(leaf_tree, fixed_tree, config.leaf_branch_edge_radius)
    if len(lb) == 0:
        raise DeformationError(
            f"no leaf node within leaf_branch_edge_radius={config.leaf_branch_edge_radius} m "
            f"of a branch node: the leaf is not attached to the branch")
    lb[:, 1] += n_leaf
    w_lb = np.full(len(lb), config.leaf_branch_weight)
    bb = fixed_tree.query_pairs(config.edge_radius, output_type="ndarray").astype(np.int64)
    bb += n_leaf
    w_bb = np.full(len(bb), config.branch_edge_weight)
    edges = np.vstack([ll, lb, bb])
    weights = np.concatenate([w_ll, w_lb, w_bb]).astype(float)
    return LeafGraph(nodes_W=np.vstack([leaf_nodes, fixed]), num_leaf=n_leaf, vein=vein,
                     edges=edges, weights=weights, leaf_points_W=leaf, point_node=point_node,
                     centre_W=centre, axis_W=axis, leaf_tree=leaf_tree)


def BuildGraspGraph(graph: LeafGraph, p_WG: np.ndarray, R_WG: np.ndarray,
                    config: DeformationConfig) -> GraspGraph:
    """Adds the gripper handle for the grasp (p_WG, R_WG) to ``graph`` and
    keeps the connected components that hold the handle (nodes with no
    path to a constrained node are dropped; components tied only to fixed
    nodes cannot move and are dropped too). Raises
    DeformationError if the grasp is more than ``max_grasp_distance`` from
    the leaf or the grasped part of the leaf has no path to a fixed node."""
    p_WG = np.asarray(p_WG, float).reshape(3)
    d_grasp, _ = graph.leaf_tree.query(p_WG)
    if d_grasp > config.max_grasp_distance:
        raise DeformationError(
            f"grasp point {np.round(p_WG, 4).tolist()} is {d_grasp:.4f} m from the nearest "
            f"leaf node (max_grasp_distance={config.max_grasp_distance} m)")
    handle = HandleGrid(p_WG, R_WG, config.handle_grid, config.handle_size)
    n_base = len(graph.nodes_W)
    n_leaf = graph.num_leaf
    h_tree = cKDTree(handle)
    w_two, w_one, w_none = config.vein_weights
    hl = _pairs(h_tree, graph.leaf_tree, config.edge_radius)
    fallback = len(hl) == 0
    if fallback:
        k = min(config.handle_fallback_neighbors, n_leaf)
        _, idx = graph.leaf_tree.query(handle, k=k)
        idx = np.asarray(idx).reshape(len(handle), k)
        hl = np.stack([np.repeat(np.arange(len(handle)), k), idx.ravel()], axis=1)
    w_hl = np.where(graph.vein[hl[:, 1]], w_one, w_none)
    hl_edges = np.stack([hl[:, 1], hl[:, 0] + n_base], axis=1)
    hh = h_tree.query_pairs(config.edge_radius, output_type="ndarray").astype(np.int64) + n_base
    fixed_tree = cKDTree(graph.nodes_W[n_leaf:])
    hf = _pairs(h_tree, fixed_tree, config.edge_radius)
    hf_edges = np.stack([hf[:, 1] + n_leaf, hf[:, 0] + n_base], axis=1)
    edges = np.vstack([graph.edges, hl_edges, hh, hf_edges])
    weights = np.concatenate([graph.weights, w_hl, np.full(len(hh), w_none),
                              np.full(len(hf), w_none)]).astype(float)
    n_all = n_base + len(handle)
    kind_all = np.full(n_all, FREE, dtype=np.int8)
    kind_all[n_leaf:n_base] = FIXED
    kind_all[n_base:] = HANDLE

    adj = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n_all, n_all))
    _, label = connected_components(adj, directed=False)
    n_lab = label.max() + 1
    has = lambda mask: np.bincount(label[mask], minlength=n_lab) > 0  # noqa: E731
    has_fixed, has_handle = has(kind_all == FIXED), has(kind_all == HANDLE)
    has_free = has(kind_all == FREE)
    handle_comps = np.unique(label[n_base:][np.isin(np.arange(len(handle)), hl[:, 0])])
    if not has_fixed[handle_comps].any():
        raise DeformationError(
            "the grasped part of the leaf has no path to a fixed (branch) node")
    # Components without the handle cannot move (their constrained nodes
    # are all fixed): the solution there is zero displacement and zero
    # energy, so they are dropped along with unconstrained components.
    keep_comp = has_handle & has_free
    keep = keep_comp[label]
    # Handle nodes are the action's known motion: keep the whole grid.
    keep[n_base:] = True
    order = np.concatenate([np.flatnonzero(keep & (kind_all == FREE)),
                            np.flatnonzero(keep & (kind_all == FIXED)),
                            np.arange(n_base, n_all)])
    new_index = np.full(n_all, -1, dtype=np.int64)
    new_index[order] = np.arange(len(order))
    e_new = new_index[edges]
    ok = (e_new >= 0).all(axis=1)
    base_index = np.where(order < n_base, order, -1)
    kind = kind_all[order]
    return GraspGraph(
        nodes_W=np.vstack([graph.nodes_W, handle])[order], kind=kind,
        edges=e_new[ok], weights=weights[ok], base_index=base_index,
        num_free=int((kind == FREE).sum()), num_fixed=int((kind == FIXED).sum()),
        num_handle=len(handle), handle_fallback=fallback,
        num_dropped=int(n_leaf - (kind == FREE).sum()))
