"""Which leaves may sleep: a leaf at rest far from the robot is frozen
(its FEM body disabled) until the robot comes near it
(``plant_scene.sleep_distance``, ``PlantWorldSim``). World frame W, metres.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def BodyBoxes(bodies: list[np.ndarray]) -> np.ndarray:
    """(B, 2, 3): each body's sample box (min, max); empty bodies get an
    inverted box that meets nothing."""
    out = np.empty((len(bodies), 2, 3))
    out[:, 0], out[:, 1] = np.inf, -np.inf
    for i, b in enumerate(bodies):
        if len(b):
            out[i] = b.min(axis=0), b.max(axis=0)
    return out


class LeafProximity:
    """A leaf's vertices (N, 3, W, m) for the sleep test: is any robot
    surface sample within a distance of them?"""

    def __init__(self, V: np.ndarray):
        self.V = np.asarray(V, float)
        self.lo, self.hi = self.V.min(axis=0), self.V.max(axis=0)
        self._tree = None

    def Near(self, bodies, distance: float) -> bool:
        """Whether a sample of ``bodies`` (the robot's surface samples, one
        (M, 3) array per body, W; with a ``boxes`` (B, 2, 3) attribute of
        min/max boxes, as ``RobotModel.SurfacePointsByBody`` gives, else
        computed here) lies within ``distance`` (m) of a vertex. Exact: only
        the bodies whose box meets the leaf's box grown by the distance, and
        their samples inside it, go to the k-d tree."""
        lo, hi = self.lo - distance, self.hi + distance
        boxes = getattr(bodies, "boxes", None)
        if boxes is None:
            boxes = BodyBoxes(bodies)
        hit = np.flatnonzero(np.all((boxes[:, 0] <= hi) & (boxes[:, 1] >= lo), axis=1))
        if not len(hit):
            return False
        P = np.vstack([bodies[i] for i in hit])
        P = P[np.all((P >= lo) & (P <= hi), axis=1)]
        if not len(P):
            return False
        if self._tree is None:
            self._tree = cKDTree(self.V)
        return bool(np.any(self._tree.query(P, distance_upper_bound=distance)[0] < distance))
