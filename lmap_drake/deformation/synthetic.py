"""A synthetic leaf on a branch, for tests and the benchmark until the
procedural plant world provides one. World frame W, metres.

Local layout (before ``X_WL``): the branch is a vertical cylinder on the z
axis; the petiole leaves it along +x; the ovate blade (widest at 40 % of its
length) lies near the x-y plane, drooping towards its tip, mirror symmetric
about the x-z plane (no sample lies on y = 0 so that voxelisation keeps the
symmetry).
"""
from __future__ import annotations

import numpy as np


def OvateLeaf(length: float = 0.12, width: float = 0.06, spacing: float = 0.0015,
              petiole_length: float = 0.02, branch_radius: float = 0.006,
              branch_length: float = 0.2, droop: float = 0.01, noise: float = 0.0,
              p_WL: np.ndarray | None = None, seed: int = 0
              ) -> tuple[np.ndarray, np.ndarray]:
    """Returns (leaf_points_W (N, 3), branch_points_W (M, 3)). ``noise`` is
    the standard deviation (m) of Gaussian sensor noise added to the leaf
    and branch points (it thickens the leaf as a depth camera does), in
    mirrored pairs so that the symmetry holds. ``p_WL`` translates the
    whole plant (default: the origin at the petiole's base on the axis)."""
    rng = np.random.default_rng(seed)
    x0 = branch_radius + petiole_length
    xs = np.arange(0.5 * spacing, length, spacing)
    pts = []
    for x in xs:
        t = x / length
        half = 0.5 * width * np.sin(np.pi * t ** 0.75)
        ys = np.arange(0.5 * spacing, half, spacing)
        for y in ys:
            pts.append((x0 + x, y))
    blade = np.array(pts)
    blade = np.vstack([blade, blade * [1.0, -1.0]])
    bz = -droop * ((blade[:, 0] - x0) / length) ** 2
    leaf = np.column_stack([blade, bz])
    # Petiole: a thin stalk from the branch surface to the blade.
    px = np.arange(branch_radius, x0 + spacing, spacing / 2)
    pet = np.column_stack([px, np.full_like(px, 0.5 * spacing), np.zeros_like(px)])
    leaf = np.vstack([leaf, pet, pet * [1.0, -1.0, 1.0]])
    # Branch: cylinder surface, angles offset so that no sample has y = 0.
    n_theta = max(8, int(round(2 * np.pi * branch_radius / spacing)) // 2 * 2)
    th = (np.arange(n_theta) + 0.5) * 2 * np.pi / n_theta
    zs = np.arange(-0.5 * branch_length, 0.5 * branch_length, spacing)
    TH, Z = np.meshgrid(th, zs, indexing="ij")
    branch = np.column_stack([branch_radius * np.cos(TH.ravel()),
                              branch_radius * np.sin(TH.ravel()), Z.ravel()])
    if noise > 0:
        def _noisy(p):
            upper = p[p[:, 1] > 0]
            upper = upper + rng.normal(scale=noise, size=upper.shape)
            upper[:, 1] = np.abs(upper[:, 1]) + 1e-9
            return np.vstack([upper, upper * [1.0, -1.0, 1.0]])
        leaf, branch = _noisy(leaf), _noisy(branch)
    offset = np.zeros(3) if p_WL is None else np.asarray(p_WL, float)
    return leaf + offset, branch + offset
