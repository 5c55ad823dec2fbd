"""Fruit visibility prediction from the camera (paper Sec. III-C-2).

The paper ray-casts an OctoMap (3 mm) from the camera and counts fruit
voxels that are the first hit along a ray. We do the equivalent in image
space, vectorised: every surface is voxelised at ``voxel`` metres; a virtual
pinhole camera at ``X_WC`` whose pixels subtend about one voxel at the fruit
casts one ray per pixel; the first voxel along a ray is the nearest one
projected into that pixel (a z-buffer). Occluder voxels are splatted over the
pixels their cube covers, so that sparse samples leave no holes. A fruit
voxel is *seen* when it is the nearest surface at its pixel.

    H_init: completed-fruit voxels seen with the observed leaf and branch
    H_k:    seen with the deformed leaf, the branch and the robot of action k
    H_max:  seen with the fruit alone
    N_vis(k) = |H_k \\ H_init|
World frame W, metres.
"""
from __future__ import annotations

import numpy as np


def VoxelCenters(points: np.ndarray, voxel: float) -> np.ndarray:
    """Unique voxel centres (M, 3) of ``points`` at ``voxel`` size."""
    if len(points) == 0:
        return np.zeros((0, 3))
    keys = np.unique(np.floor(np.asarray(points) / voxel).astype(np.int64), axis=0)
    return (keys + 0.5) * voxel


class VisibilityModel:
    """Holds the camera and the completed fruit's surface voxels; answers
    which of them are seen given occluders."""

    def __init__(self, X_WC: np.ndarray, fruit_surface_W: np.ndarray, voxel: float = 0.003):
        self.voxel = voxel
        self.X_CW = np.linalg.inv(np.asarray(X_WC, float))
        self.fruit_W = VoxelCenters(fruit_surface_W, voxel)
        if len(self.fruit_W) == 0:
            raise ValueError("visibility needs a non-empty fruit surface")
        p_C = self._to_camera(self.fruit_W)
        depth = float(np.median(p_C[:, 2]))
        self.f = depth / voxel              # one pixel ~ one voxel at the fruit
        uv = self._project(p_C)
        margin = 40
        self.lo = uv.min(axis=0) - margin
        self.shape = tuple((uv.max(axis=0) - self.lo + margin + 1).astype(int)[::-1])
        self._fruit_pix = self._pixels(uv)
        self._fruit_z = p_C[:, 2]
        self._z_far = float(p_C[:, 2].max()) + voxel
        self.max_seen = self.Seen(np.zeros((0, 3)))

    def _to_camera(self, p_W: np.ndarray) -> np.ndarray:
        return p_W @ self.X_CW[:3, :3].T + self.X_CW[:3, 3]

    def _project(self, p_C: np.ndarray) -> np.ndarray:
        z = np.maximum(p_C[:, 2], 1e-6)
        return np.round(self.f * p_C[:, :2] / z[:, None]).astype(np.int64)

    def _pixels(self, uv: np.ndarray) -> np.ndarray:
        rc = uv - self.lo
        h, w = self.shape
        inside = (rc[:, 0] >= 0) & (rc[:, 0] < w) & (rc[:, 1] >= 0) & (rc[:, 1] < h)
        return np.where(inside, rc[:, 1] * w + rc[:, 0], -1)

    def Seen(self, occluders_W: np.ndarray) -> np.ndarray:
        """Boolean mask over the fruit voxels: seen from the camera with
        ``occluders_W`` (points, any density) in the scene."""
        h, w = self.shape
        zbuf = np.full(h * w, np.inf)
        occ = np.asarray(occluders_W, float).reshape(-1, 3)
        if len(occ):
            # only what lies in front of the fruit's far side and projects
            # into the window can occlude it
            p_C = self._to_camera(occ)
            keep = (p_C[:, 2] > 1e-3) & (p_C[:, 2] < self._z_far)
            uv = self.f * p_C[keep, :2] / p_C[keep, 2:3] - self.lo
            h, w = self.shape
            inwin = (uv[:, 0] > -3) & (uv[:, 0] < w + 3) & (uv[:, 1] > -3) & (uv[:, 1] < h + 3)
            occ = VoxelCenters(occ[keep][inwin], self.voxel)
        if len(occ):
            p_C = self._to_camera(occ)
            front = p_C[:, 2] > 1e-3
            p_C = p_C[front]
            uv = self._project(p_C)
            # splat radius: the voxel's pixel footprint at its depth
            rad = np.ceil(0.5 * self.f * self.voxel * np.sqrt(2) / p_C[:, 2]).astype(int)
            all_pix, all_z = [], []
            for r in np.unique(rad):
                sel = rad == r
                for du in range(-r, r + 1):
                    for dv in range(-r, r + 1):
                        pix = self._pixels(uv[sel] + [du, dv])
                        ok = pix >= 0
                        all_pix.append(pix[ok])
                        all_z.append(p_C[sel, 2][ok])
            _MinInto(zbuf, np.concatenate(all_pix), np.concatenate(all_z))
        fz = np.full(h * w, np.inf)
        ok = self._fruit_pix >= 0
        _MinInto(fz, self._fruit_pix[ok], self._fruit_z[ok])
        tol = 0.75 * self.voxel
        seen = np.zeros(len(self.fruit_W), bool)
        pix = self._fruit_pix[ok]
        z = self._fruit_z[ok]
        seen[ok] = (z <= fz[pix] + tol) & (z < zbuf[pix] - tol)
        return seen


def _MinInto(buf: np.ndarray, idx: np.ndarray, val: np.ndarray) -> None:
    """buf[i] = min(buf[i], min of val where idx == i) (a fast np.minimum.at)."""
    if len(idx) == 0:
        return
    order = np.lexsort((val, idx))
    idx, val = idx[order], val[order]
    first = np.r_[True, idx[1:] != idx[:-1]]
    buf[idx[first]] = np.minimum(buf[idx[first]], val[first])


def CountNewlySeen(seen_k: np.ndarray, seen_init: np.ndarray) -> int:
    """N_vis = |H_k \\ H_init|."""
    return int(np.count_nonzero(seen_k & ~seen_init))
