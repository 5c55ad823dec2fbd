"""Distances and ray casts between the parts of a multi-fruit plant
(branches, fruits, leaves; world frame, metres), used to place its leaves
and to check them apart."""
from __future__ import annotations

import numpy as np
import trimesh

from lmap_drake.plants.generator import SIGN_RAYS
from lmap_drake.plants.leaf import BoundaryTriangles
from lmap_drake.plants.multi import Branch


def SegmentDistance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (m) from points (N, 3) to the segment a-b."""
    ab = b - a
    t = np.clip((points - a) @ ab / max(ab @ ab, 1e-12), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * ab), axis=1)


def BranchClearance(points: np.ndarray, branch: Branch) -> np.ndarray:
    """Distance (m) from points to the branch's tube surface (negative inside)."""
    P = branch.points_W
    d = np.min([SegmentDistance(points, P[k], P[k + 1]) for k in range(len(P) - 1)], axis=0)
    return d - branch.radius


def BranchTube(branch: Branch, sections: int = 12) -> trimesh.Trimesh:
    P = branch.points_W
    return trimesh.util.concatenate([
        trimesh.creation.cylinder(branch.radius, segment=P[k:k + 2], sections=sections)
        for k in range(len(P) - 1)])


def RaycastScene(meshes):
    """An open3d ray-casting scene of the triangle meshes."""
    import open3d as o3d
    sc = o3d.t.geometry.RaycastingScene()
    for m in meshes:
        sc.add_triangles(o3d.core.Tensor(np.asarray(m.vertices, np.float32)),
                         o3d.core.Tensor(np.asarray(m.faces, np.uint32)))
    return sc


def SurfaceDistance(meshes: list, points: np.ndarray) -> np.ndarray:
    """Signed distance (m, negative inside) of points to the closed meshes."""
    import open3d as o3d
    if not meshes:
        return np.full(len(points), np.inf)
    q = o3d.core.Tensor(np.asarray(points, np.float32))
    return RaycastScene(meshes).compute_signed_distance(q, nsamples=SIGN_RAYS).numpy().astype(float)


def MeshesCross(a: trimesh.Trimesh, b: trimesh.Trimesh) -> bool:
    """True if an edge of one triangle mesh passes through a face of the other."""
    import open3d as o3d
    for m, other in ((a, b), (b, a)):
        e = m.edges_unique
        p0, p1 = m.vertices[e[:, 0]], m.vertices[e[:, 1]]
        d = p1 - p0
        length = np.linalg.norm(d, axis=1)
        rays = o3d.core.Tensor(np.c_[p0, d / length[:, None]].astype(np.float32))
        t = RaycastScene([other]).cast_rays(rays)["t_hit"].numpy()
        if np.any(t < length):
            return True
    return False


def LeafLeafGap(a: trimesh.Trimesh, b: trimesh.Trimesh) -> float:
    """Smallest vertex-to-surface distance (m) between two closed leaf
    surfaces, both ways; negative if they interpenetrate."""
    d = min(SurfaceDistance([b], a.vertices).min(), SurfaceDistance([a], b.vertices).min())
    if d > 0 and MeshesCross(a, b):
        return -1e-3
    return float(d)


class FruitView:
    """camera0's view of one fruit without leaves: surface samples that the
    camera sees past the stem, shoots and other fruits."""

    def __init__(self, fruit: trimesh.Trimesh, others: list, p_WC: np.ndarray, n: int = 1200):
        import open3d as o3d
        samples = trimesh.sample.sample_surface_even(fruit, n, seed=0)[0]
        d = samples - p_WC[None]
        self.dist = np.linalg.norm(d, axis=1)
        self.rays = o3d.core.Tensor(np.c_[np.repeat(p_WC[None], len(d), 0),
                                          d / self.dist[:, None]].astype(np.float32))
        hit = RaycastScene([fruit] + others).cast_rays(self.rays)
        self.visible = (hit["geometry_ids"].numpy() == 0) & \
            (np.abs(hit["t_hit"].numpy() - self.dist) < 2e-3)

    def Hidden(self, leaves: list) -> np.ndarray:
        """Mask over samples: visible without leaves, hidden by ``leaves``."""
        if not leaves or not self.visible.any():
            return np.zeros(len(self.dist), bool)
        t = RaycastScene(leaves).cast_rays(self.rays)["t_hit"].numpy()
        return self.visible & (t < self.dist - 1e-3)

    def Occlusion(self, leaves: list) -> float:
        n = self.visible.sum()
        return float(self.Hidden(leaves).sum() / n) if n else 0.0


def LeafLeafPenetration(leaves_V: list, tets: list) -> np.ndarray:
    """(L, L) matrix: how deep (m, >= 0) the vertices of leaf a lie inside
    leaf b's closed surface (0 when apart), for leaf vertex arrays at any
    configuration (rest or simulated)."""
    n = len(leaves_V)
    out = np.zeros((n, n))
    surfs = [trimesh.Trimesh(V, BoundaryTriangles(T), process=False)
             for V, T in zip(leaves_V, tets)]
    for a in range(n):
        for b in range(n):
            if a != b:
                out[a, b] = max(0.0, -float(SurfaceDistance([surfs[b]], leaves_V[a]).min()))
    return out
