"""Shape-completion metrics of paper Table I (inputs in metres, world frame;
outputs in cm, cm^3 and degrees).

* Chamfer distance (cm): mean of the two directional mean nearest-neighbour
  distances between dense uniform surface samples of both meshes.
* Volume error (cm^3): |V_est - V_gt| of the closed meshes.
* Centre error (cm): distance between the volume centroids of the meshes.
* Angle error (deg): angle between the peduncle axes (unit vectors).
"""
from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree


def SampleSurface(vertices, faces, n: int, seed: int = 0) -> np.ndarray:
    """``n`` points uniformly on the mesh surface (area-weighted)."""
    mesh = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces), process=False)
    pts, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return np.asarray(pts)


def ChamferCm(points_a: np.ndarray, points_b: np.ndarray) -> float:
    """Symmetric Chamfer distance (cm) between two point sets in metres:
    0.5 * (mean_a min_b |a-b| + mean_b min_a |a-b|)."""
    da, _ = cKDTree(points_b).query(points_a)
    db, _ = cKDTree(points_a).query(points_b)
    return float(50.0 * (da.mean() + db.mean()))


def MeshChamferCm(va, fa, vb, fb, n: int = 20000, seed: int = 0) -> float:
    """Chamfer distance (cm) between two meshes from ``n`` samples each."""
    return ChamferCm(SampleSurface(va, fa, n, seed), SampleSurface(vb, fb, n, seed + 1))


def MeshVolume(vertices, faces) -> float:
    """Enclosed volume (m^3) of a closed, consistently wound mesh."""
    v = np.asarray(vertices, float)[np.asarray(faces)]
    return float(abs(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum()) / 6.0)


def MeshCentroid(vertices, faces) -> np.ndarray:
    """Volume centroid (m) of a closed mesh (signed tetrahedra to the origin)."""
    v = np.asarray(vertices, float)[np.asarray(faces)]
    vol = np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])) / 6.0
    if abs(vol.sum()) < 1e-15:
        return np.asarray(vertices, float).mean(0)
    return (vol[:, None] * v.sum(1) / 4.0).sum(0) / vol.sum()


def VolumeErrorCm3(va, fa, vb, fb) -> float:
    return abs(MeshVolume(va, fa) - MeshVolume(vb, fb)) * 1e6


def CenterErrorCm(center_a, center_b) -> float:
    return float(np.linalg.norm(np.asarray(center_a) - np.asarray(center_b)) * 100.0)


def AngleErrorDeg(axis_a, axis_b) -> float:
    a = np.asarray(axis_a, float) / np.linalg.norm(axis_a)
    b = np.asarray(axis_b, float) / np.linalg.norm(axis_b)
    return float(np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0))))


def ShapeMetrics(est_vertices, est_faces, est_axis, gt_vertices, gt_faces, gt_axis,
                 n: int = 20000, seed: int = 0) -> dict:
    """All four metrics of an estimate against the ground truth (both in W, m)."""
    return dict(
        chamfer_cm=MeshChamferCm(est_vertices, est_faces, gt_vertices, gt_faces, n, seed),
        volume_err_cm3=VolumeErrorCm3(est_vertices, est_faces, gt_vertices, gt_faces),
        center_err_cm=CenterErrorCm(MeshCentroid(est_vertices, est_faces),
                                    MeshCentroid(gt_vertices, gt_faces)),
        angle_err_deg=AngleErrorDeg(est_axis, gt_axis))
