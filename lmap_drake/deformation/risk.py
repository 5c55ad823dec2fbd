"""Damage-risk measures of a predicted deformation beyond the total ARAP
energy. World frame W, metres; stretches are dimensionless (1 = unstretched).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from lmap_drake.deformation.graph import FIXED, FREE


def LocalStretch(rest_W: np.ndarray, deformed_W: np.ndarray, centres: np.ndarray,
                 neighbourhood: float, max_neighbours: int = 24) -> np.ndarray:
    """Largest length ratio (deformed / rest) of the segments from each node
    index in ``centres`` to the nodes within ``neighbourhood`` (m) of it
    (rest ``rest_W``, deformed ``deformed_W``, both (n, 3)): the maximum
    principal stretch sampled along the graph's own directions (a rigid
    motion gives 1). Unlike a fitted deformation gradient it stays well
    posed on a petiole one or two nodes wide. NaN where no neighbour."""
    rest = np.asarray(rest_W, float)
    cur = np.asarray(deformed_W, float)
    centres = np.asarray(centres, int)
    if len(centres) == 0:
        return np.zeros(0)
    k = min(max_neighbours + 1, len(rest))
    d, j = cKDTree(rest).query(rest[centres], k=k, distance_upper_bound=neighbourhood)
    d, j = d.reshape(len(centres), k), j.reshape(len(centres), k)
    ok = np.isfinite(d) & (d > 1e-9)
    j = np.where(ok, j, centres[:, None])
    ratio = np.linalg.norm(cur[j] - cur[centres][:, None], axis=2) / np.where(ok, d, 1.0)
    ratio[~ok] = -np.inf
    s = ratio.max(axis=1)
    s[~ok.any(axis=1)] = np.nan
    return s


def AttachmentStretch(nodes_W: np.ndarray, node_kind: np.ndarray, deformed_nodes_W: np.ndarray,
                      ring: float = 0.02, neighbourhood: float = 0.012,
                      percentile: float = 50.0) -> float:
    """``percentile`` of the local stretch (``LocalStretch``) of the free
    leaf nodes within ``ring`` (m) of a fixed (branch) node: the graph's
    analogue of the stretch at the petiole that loads it (the plant world's
    petiole force is E A (median attachment stretch - 1)). 1.0 if no free
    node lies in the ring."""
    kind = np.asarray(node_kind)
    free = np.flatnonzero(kind == FREE)
    fixed = np.flatnonzero(kind == FIXED)
    nodes = np.asarray(nodes_W, float)
    if len(free) == 0 or len(fixed) == 0:
        return 1.0
    d, _ = cKDTree(nodes[fixed]).query(nodes[free])
    ring_nodes = free[d <= ring]
    if len(ring_nodes) == 0:
        return 1.0
    s = LocalStretch(nodes, deformed_nodes_W, ring_nodes, neighbourhood)
    s = s[np.isfinite(s)]
    return float(np.percentile(s, percentile)) if len(s) else 1.0
