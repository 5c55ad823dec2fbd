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

Over a set of shape hypotheses (``VisibilityModel`` given one surface per
hypothesis, the estimate first; ``planner.visibility_shapes: expected``)
every hypothesis's voxels share one grid: the occluders are splatted once
and each voxel is compared with its own hypothesis's front at its pixel.
Counts (``Count``) are then the mean over the hypotheses of the fraction
seen, in units of the estimate's ``max_seen`` voxels: a fraction
count / count(max_seen) is the expected visible fraction.
World frame W, metres.
"""
from __future__ import annotations

import numpy as np


def VoxelCenters(points: np.ndarray, voxel: float) -> np.ndarray:
    """Unique voxel centres (M, 3) of ``points`` at ``voxel`` size."""
    if len(points) == 0:
        return np.zeros((0, 3))
    k = np.floor(np.asarray(points) / voxel).astype(np.int64)
    lo = k.min(axis=0)
    k -= lo
    if k.max() < (1 << 21):
        # one int64 key per voxel (x, y, z in 21 bits each, x highest): the
        # same lexicographic order as np.unique(axis=0), several times faster
        u = np.unique((k[:, 0] << 42) | (k[:, 1] << 21) | k[:, 2])
        keys = np.stack([u >> 42, (u >> 21) & 0x1FFFFF, u & 0x1FFFFF], axis=1) + lo
    else:
        keys = np.unique(k, axis=0) + lo
    return (keys + 0.5) * voxel


# Upper bound on the visibility grid (pixels): a 3 mm-voxel fruit seen
# anywhere in a 640 x 480 image needs far less. A larger window (a fruit
# estimate of absurd size, or spanning the camera plane) is made coarser.
MAX_GRID_PIXELS = 4_000_000
NEAR = 0.01   # m: voxels closer to the camera plane than this are not seen


class VisibilityModel:
    """Holds the camera and the completed fruit's surface voxels; answers
    which of them are seen given occluders. ``fruit_surface_W``: surface
    points (W, m), or a list of them, one per shape hypothesis (the
    estimate first): then the masks run over all their voxels (``group``
    says whose) and ``Count`` weighs them (see the module docstring).

    The grid covers only the fruit voxels in front of the camera (depth >
    ``NEAR``) and, when ``image_tan`` = (x_min, x_max, y_min, y_max) (the
    camera image's extent as tangents x/z, y/z of the optical frame) is
    given, inside the image; voxels outside are never seen. So a camera
    looking away sees nothing (``max_seen`` all False) instead of asking for
    an unbounded grid; the grid never exceeds ``MAX_GRID_PIXELS``."""

    def __init__(self, X_WC: np.ndarray, fruit_surface_W: np.ndarray, voxel: float = 0.003,
                 image_tan: tuple | None = None):
        self.voxel = voxel
        self.X_CW = np.linalg.inv(np.asarray(X_WC, float))
        surfaces = (list(fruit_surface_W) if isinstance(fruit_surface_W, (list, tuple))
                    else [fruit_surface_W])
        voxels = [VoxelCenters(np.asarray(s, float).reshape(-1, 3), voxel) for s in surfaces]
        self.fruit_W = np.vstack(voxels)
        # the shape hypothesis each voxel belongs to (0: the estimate)
        self.group = np.repeat(np.arange(len(voxels)), [len(v) for v in voxels])
        if len(voxels[0]) == 0:
            raise ValueError("visibility needs a non-empty fruit surface")
        p_C = self._to_camera(self.fruit_W)
        z = p_C[:, 2]
        visible = np.isfinite(p_C).all(axis=1) & (z > NEAR)
        if image_tan is not None and visible.any():
            tx, ty = p_C[:, 0] / np.maximum(z, NEAR), p_C[:, 1] / np.maximum(z, NEAR)
            x0, x1, y0, y1 = image_tan
            visible &= (tx >= x0) & (tx <= x1) & (ty >= y0) & (ty <= y1)
        self._visible = visible
        depth = float(np.median(z[visible])) if visible.any() else 1.0
        self.f = depth / voxel              # one pixel ~ one voxel at the fruit
        margin = 40
        if visible.any():
            uv = self._project(p_C[visible])
            lo, hi = uv.min(axis=0), uv.max(axis=0)
            cells = float(np.prod(hi - lo + 2 * margin + 1))
            if cells > MAX_GRID_PIXELS:      # coarser pixels, bounded grid
                self.f *= float(np.sqrt(MAX_GRID_PIXELS / cells)) * 0.9
                margin = 4
        uv = self._project(p_C)
        if visible.any():
            self.lo = uv[visible].min(axis=0) - margin
            self.shape = tuple((uv[visible].max(axis=0) - self.lo + margin + 1)
                               .astype(int)[::-1])
        else:
            self.lo, self.shape = np.zeros(2, np.int64), (1, 1)
        self._fruit_pix = np.where(visible, self._pixels(uv), -1)
        self._fruit_z = z
        self._z_far = float(z[visible].max()) + voxel if visible.any() else NEAR
        # each hypothesis's own z-buffer (the nearest of its voxels per
        # pixel; ``_fruit_zbuf``: the estimate's) read at each of its voxels
        ok = self._fruit_pix >= 0
        self._front_z = np.full(len(self.fruit_W), np.inf)
        for g in range(len(voxels)):
            zbuf = np.full(int(np.prod(self.shape)), np.inf)
            mine = ok & (self.group == g)
            _MinInto(zbuf, self._fruit_pix[mine], self._fruit_z[mine])
            self._front_z[mine] = zbuf[self._fruit_pix[mine]]
            if g == 0:
                self._fruit_zbuf = zbuf
        self.max_seen = self.Seen(np.zeros((0, 3)))
        # per voxel: what it adds to ``Count`` (1 with one surface)
        self.weight = np.ones(len(self.fruit_W))
        if len(voxels) > 1:
            n_g = np.bincount(self.group[self.max_seen], minlength=len(voxels)).astype(float)
            ref = n_g[0] if n_g[0] > 0 else (n_g[n_g > 0].mean() if n_g.any() else 0.0)
            per = np.where(n_g > 0, ref / np.maximum(n_g, 1) / max(1, np.count_nonzero(n_g)),
                           0.0)
            self.weight = per[self.group]

    @property
    def num_shapes(self) -> int:
        """How many shapes the voxels come from (1: the estimate alone)."""
        return int(self.group.max()) + 1 if len(self.group) else 0

    def Count(self, mask: np.ndarray) -> int:
        """The number of voxels of ``mask`` (over ``fruit_W``); over several
        shapes the mean over them of the fraction of each one's ``max_seen``
        in ``mask``, times the estimate's ``max_seen`` count (rounded)."""
        mask = np.asarray(mask, bool)
        if self.num_shapes <= 1:
            return int(np.count_nonzero(mask))
        return int(round(float(self.weight[mask].sum())))

    def Observed(self, points_W: np.ndarray) -> np.ndarray:
        """The fruit voxels a view has already shown: those the camera sees
        of the fruit (``max_seen``) on a pixel that one of ``points_W`` (W,
        m; the fruit's points observed in earlier views, the camera fixed)
        covers, splatted as ``ZBuffer`` splats occluders. By pixel, not by
        distance: the model counts a rim voxel seen wherever the fruit's
        front at its pixel is, and no observed point lies on it."""
        P = np.asarray(points_W, float).reshape(-1, 3)
        P = P[np.isfinite(P).all(axis=1)]
        out = np.zeros(len(self.fruit_W), bool)
        if not len(P):
            return out
        covered = np.isfinite(self.ZBuffer(P))
        ok = self._fruit_pix >= 0
        out[ok] = covered[self._fruit_pix[ok]]
        return out & self.max_seen

    def _to_camera(self, p_W: np.ndarray) -> np.ndarray:
        return p_W @ self.X_CW[:3, :3].T + self.X_CW[:3, 3]

    def _project(self, p_C: np.ndarray) -> np.ndarray:
        z = np.maximum(p_C[:, 2], NEAR)
        uv = np.nan_to_num(self.f * p_C[:, :2] / z[:, None], nan=-2.0**40)
        return np.round(np.clip(uv, -2.0**40, 2.0**40)).astype(np.int64)

    def _pixels(self, uv: np.ndarray) -> np.ndarray:
        rc = uv - self.lo
        h, w = self.shape
        inside = (rc[:, 0] >= 0) & (rc[:, 0] < w) & (rc[:, 1] >= 0) & (rc[:, 1] < h)
        return np.where(inside, rc[:, 1] * w + rc[:, 0], -1)

    def ZBuffer(self, occluders_W: np.ndarray, base: np.ndarray | None = None) -> np.ndarray:
        """The occluders' depth buffer over the grid (flat, camera z in m,
        inf where none), min-combined with ``base`` (e.g. the buffer of the
        occluders every action shares, computed once). The grid is global
        (voxels at multiples of ``voxel``), so the buffer of a union of point
        sets equals the min of their buffers."""
        h, w = self.shape
        zbuf = np.full(h * w, np.inf) if base is None else np.array(base, float)
        occ = np.asarray(occluders_W, float).reshape(-1, 3)
        if len(occ):
            # only what lies in front of the fruit's far side and projects
            # into the window can occlude it
            p_C = self._to_camera(occ)
            keep = (p_C[:, 2] > NEAR) & (p_C[:, 2] < self._z_far)
            uv = self.f * p_C[keep, :2] / p_C[keep, 2:3] - self.lo
            inwin = (uv[:, 0] > -3) & (uv[:, 0] < w + 3) & (uv[:, 1] > -3) & (uv[:, 1] < h + 3)
            occ = VoxelCenters(occ[keep][inwin], self.voxel)
        if len(occ):
            p_C = self._to_camera(occ)
            front = p_C[:, 2] > NEAR
            p_C = p_C[front]
            uv = self._project(p_C)
            # splat radius: the voxel's pixel footprint at its depth
            rad = np.ceil(0.5 * self.f * self.voxel * np.sqrt(2) / p_C[:, 2]).astype(int)
            rad = np.minimum(rad, 64)          # bounded work for an occluder at the lens
            # Each voxel covers the (2r+1)^2 pixels around its projection:
            # a min-filter of the point buffer of each radius group (the same
            # result as splatting every point, at image-filter cost).
            from scipy.ndimage import minimum_filter
            for r in np.unique(rad):
                sel = rad == r
                pix = self._pixels(uv[sel])
                ok = pix >= 0
                # points projecting just outside the window still cover it
                if r > 0:
                    near = ~ok & np.all(np.abs(uv[sel] - np.clip(
                        uv[sel], self.lo, self.lo + [w - 1, h - 1])) <= r, axis=1)
                else:
                    near = np.zeros_like(ok)
                pts = np.full(h * w, np.inf)
                _MinInto(pts, pix[ok], p_C[sel, 2][ok])
                if near.any():
                    pts_out = self._SplatOutside(uv[sel][near], p_C[sel, 2][near], r)
                    _MinInto(zbuf, *pts_out)
                if r > 0:
                    pts = minimum_filter(pts.reshape(h, w), size=2 * r + 1, mode="constant",
                                         cval=np.inf).ravel()
                np.minimum(zbuf, pts, out=zbuf)
        return zbuf

    def _SplatOutside(self, uv: np.ndarray, z: np.ndarray, r: int) -> tuple:
        """Pixels and depths of voxels projecting outside the window whose
        (2r+1)^2 footprint reaches into it (explicit splat: few points)."""
        all_pix, all_z = [], []
        for du in range(-r, r + 1):
            for dv in range(-r, r + 1):
                pix = self._pixels(uv + [du, dv])
                ok = pix >= 0
                all_pix.append(pix[ok])
                all_z.append(z[ok])
        return np.concatenate(all_pix), np.concatenate(all_z)

    def Seen(self, occluders_W: np.ndarray, base_zbuf: np.ndarray | None = None) -> np.ndarray:
        """Boolean mask over the fruit voxels: seen from the camera with
        ``occluders_W`` (points, any density) in the scene, plus the
        occluders already in ``base_zbuf`` (from ``ZBuffer``)."""
        zbuf = self.ZBuffer(occluders_W, base_zbuf)
        ok = self._fruit_pix >= 0
        tol = 0.75 * self.voxel
        seen = np.zeros(len(self.fruit_W), bool)
        pix = self._fruit_pix[ok]
        z = self._fruit_z[ok]
        seen[ok] = (z <= self._front_z[ok] + tol) & (z < zbuf[pix] - tol)
        return seen


def _MinInto(buf: np.ndarray, idx: np.ndarray, val: np.ndarray) -> None:
    """buf[i] = min(buf[i], min of val where idx == i) (numpy >= 2's
    ``ufunc.at`` is fast: ~100x a sort-based reduction here)."""
    if len(idx) == 0:
        return
    np.minimum.at(buf, idx, val)


def CountNewlySeen(seen_k: np.ndarray, seen_init: np.ndarray,
                   vis: VisibilityModel | None = None) -> int:
    """N_vis = |H_k \\ H_init| (counted by ``vis.Count`` when given: over a
    hypothesis set, its expectation)."""
    new = seen_k & ~seen_init
    return vis.Count(new) if vis is not None else int(np.count_nonzero(new))
