"""Branch completion (paper Sec. III-A-2; world frame W, metres).

1. PCA of the branch points gives the axis; the extent along it gives the
   two end points.
2. The points are cut into slabs (``slab`` m thick) along the axis; in each
   slab a circle is fitted to the points projected on the cross-section
   (algebraic least squares, which works on the half-cylinder a camera
   sees). The radius is ``radius_factor`` times the mean over slabs of the
   mean radial distance from the fitted centres (the authors' release uses
   0.9 x the slab mean).
3. A closed cylinder mesh (~``mesh_res`` m edges) along the axis line
   (through the slab centres) is deformed toward the points with
   as-rigid-as-possible deformation (Sorkine & Alexa 2007, uniform edge
   weights, soft handle constraints): every iteration matches each branch
   point to its nearest *camera-visible* vertex (normal facing the camera)
   within ``match_distance``; matched vertices become handles pulled to the
   mean of their points; local rotations / global solve alternate, and the
   loop stops when the energy stops decreasing.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.spatial import cKDTree

from lmap_drake.shape.config import BranchCompletionConfig
from lmap_drake.types import BranchEstimate


def PcaAxis(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centroid, unit principal axis); the axis points toward +z when it
    has a z component (deterministic sign)."""
    c = points.mean(0)
    _, _, vt = np.linalg.svd(points - c, full_matrices=False)
    a = vt[0]
    if a[2] < 0 or (a[2] == 0 and a[0] < 0):
        a = -a
    return c, a / np.linalg.norm(a)


def _basis(axis):
    tmp = np.array([1.0, 0, 0]) if abs(axis[0]) < 0.9 else np.array([0, 1.0, 0])
    u = np.cross(axis, tmp)
    u /= np.linalg.norm(u)
    return u, np.cross(axis, u)


def _fit_circle(xy: np.ndarray):
    """Algebraic (Kasa) circle fit: centre (2,), radius."""
    A = np.c_[2 * xy, np.ones(len(xy))]
    b = (xy ** 2).sum(1)
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    c = sol[:2]
    r2 = sol[2] + c @ c
    return c, np.sqrt(max(r2, 0.0))


def EstimateCylinder(points: np.ndarray, slab: float = 0.01):
    """Axis (centroid, direction), extent (s_min, s_max along the axis),
    radius (mean slab radial distance from fitted circle centres) and the
    axis offset in the cross-section plane (m)."""
    c, a = PcaAxis(points)
    u, v = _basis(a)
    s = (points - c) @ a
    xy = np.c_[(points - c) @ u, (points - c) @ v]
    radii, centres = [], []
    for lo in np.arange(s.min(), s.max(), slab):
        m = (s >= lo) & (s < lo + slab)
        if m.sum() < 8:
            continue
        cc, r = _fit_circle(xy[m])
        rad = np.linalg.norm(xy[m] - cc, axis=1).mean()
        spread = np.ptp(xy[m], axis=0).max()
        if not np.isfinite(r) or r > 2.0 * spread + 1e-3 or r < 1e-4:
            cc = xy[m].mean(0)            # degenerate slab: centroid fallback
            rad = np.linalg.norm(xy[m] - cc, axis=1).mean()
        radii.append(rad)
        centres.append(cc)
    if radii:
        radius = float(np.mean(radii))
        off = np.median(np.array(centres), axis=0)
    else:
        radius = float(np.linalg.norm(xy - xy.mean(0), axis=1).mean())
        off = xy.mean(0)
    center = c + off[0] * u + off[1] * v
    return center, a, float(s.min()), float(s.max()), radius


def CylinderMesh(center, axis, s0, s1, radius, res=0.003):
    """Closed cylinder (caps fanned to a centre vertex) from ``center +
    s0*axis`` to ``center + s1*axis``. Returns vertices, faces (outward)."""
    u, v = _basis(axis)
    n_a = max(12, int(np.ceil(2 * np.pi * radius / res)))
    n_s = max(2, int(np.ceil((s1 - s0) / res)) + 1)
    ang = 2 * np.pi * np.arange(n_a) / n_a
    ring = np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v
    ss = np.linspace(s0, s1, n_s)
    verts = (center + ss[:, None, None] * axis + radius * ring[None]).reshape(-1, 3)
    faces = []
    for i in range(n_s - 1):
        for j in range(n_a):
            a0, a1 = i * n_a + j, i * n_a + (j + 1) % n_a
            b0, b1 = a0 + n_a, a1 + n_a
            faces += [[a0, a1, b1], [a0, b1, b0]]
    bot = len(verts)
    top = bot + 1
    verts = np.vstack([verts, center + s0 * axis, center + s1 * axis])
    for j in range(n_a):
        faces.append([bot, (j + 1) % n_a, j])
        k = (n_s - 1) * n_a
        faces.append([top, k + j, k + (j + 1) % n_a])
    return verts, np.array(faces, np.int64)


def VertexNormals(verts, faces):
    n = np.zeros_like(verts)
    fn = np.cross(verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]])
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


class Arap:
    """ARAP with uniform edge weights and soft handles:
    E = sum_ij |(p_i - p_j) - R_i (q_i - q_j)|^2 + w sum_h |p_h - t_h|^2."""

    def __init__(self, verts, faces):
        self.q = np.asarray(verts, float)
        e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        e = np.unique(np.sort(e, 1), axis=0)
        self.i, self.j = np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]]  # directed
        n = len(verts)
        deg = np.bincount(self.i, minlength=n).astype(float)
        self.L = (sp.diags(deg) - sp.coo_matrix((np.ones(len(self.i)), (self.i, self.j)),
                                                 shape=(n, n))).tocsc()

    def rotations(self, p):
        dq = self.q[self.i] - self.q[self.j]
        dp = p[self.i] - p[self.j]
        S = np.zeros((len(self.q), 3, 3))
        np.add.at(S, self.i, dq[:, :, None] * dp[:, None, :])
        U, _, Vt = np.linalg.svd(S)
        R = np.einsum("nji,nkj->nik", Vt, U)      # V U^T
        bad = np.linalg.det(R) < 0
        if bad.any():
            U[bad, :, 2] *= -1
            R[bad] = np.einsum("nji,nkj->nik", Vt[bad], U[bad])
        return R

    def energy(self, p, R, handles, targets, w):
        dq = self.q[self.i] - self.q[self.j]
        dp = p[self.i] - p[self.j]
        r = dp - np.einsum("nab,nb->na", R[self.i], dq)
        e = 0.5 * (r ** 2).sum()
        if len(handles):
            e += w * ((p[handles] - targets) ** 2).sum()
        return float(e)

    def solve(self, p, R, handles, targets, w):
        n = len(self.q)
        dq = self.q[self.i] - self.q[self.j]
        rhs_e = 0.5 * np.einsum("nab,nb->na", R[self.i] + R[self.j], dq)
        b = np.zeros((n, 3))
        np.add.at(b, self.i, rhs_e)
        H = np.zeros(n)
        H[handles] = w
        A = self.L + sp.diags(H)
        b[handles] += w * targets
        # Unconstrained directions (no handles at all) are fixed by a tiny
        # anchor to the current positions.
        A = A + sp.identity(n) * 1e-8
        b += 1e-8 * p
        lu = spla.splu(A.tocsc())
        return np.stack([lu.solve(b[:, k]) for k in range(3)], 1)


def CompleteBranch(points_W: np.ndarray, camera_W: np.ndarray,
                   params: BranchCompletionConfig | None = None) -> BranchEstimate:
    """Completed branch mesh and surface samples (W, m) from branch points."""
    P = params or BranchCompletionConfig()
    pts = np.asarray(points_W, float)
    if len(pts) < 10:
        raise ValueError("branch completion needs at least 10 branch points")
    center, axis, s0, s1, radius = EstimateCylinder(pts, P.slab)
    radius *= P.radius_factor
    verts, faces = CylinderMesh(center, axis, s0, s1, radius, P.mesh_res)
    arap = Arap(verts, faces)
    p = verts.copy()
    R = np.repeat(np.eye(3)[None], len(p), 0)
    tree_pts = pts
    prev = np.inf
    for it in range(P.max_iterations):
        nrm = VertexNormals(p, faces)
        visible = np.einsum("ij,ij->i", nrm, camera_W - p) > 0
        vis_idx = np.flatnonzero(visible)
        d, k = cKDTree(p[vis_idx]).query(tree_pts, distance_upper_bound=P.match_distance)
        ok = np.isfinite(d)
        hv = vis_idx[k[ok]]
        if len(hv) == 0:
            break
        handles, inv = np.unique(hv, return_inverse=True)
        targets = np.zeros((len(handles), 3))
        np.add.at(targets, inv, tree_pts[ok])
        targets /= np.bincount(inv)[:, None]
        R = arap.rotations(p)
        p_new = arap.solve(p, R, handles, targets, P.handle_weight)
        R = arap.rotations(p_new)
        e = arap.energy(p_new, R, handles, targets, P.handle_weight)
        if e >= prev * (1 - P.relative_tolerance):
            if e < prev:
                p = p_new
            break
        p, prev = p_new, e
    import trimesh
    mesh = trimesh.Trimesh(p, faces, process=False)
    n = max(200, int(mesh.area / P.sample_spacing ** 2))
    samples, _ = trimesh.sample.sample_surface(mesh, n, seed=0)
    _, a = PcaAxis(p)
    return BranchEstimate(vertices_W=p, faces=faces, samples_W=np.asarray(samples), axis_W=a)


def SplitBranchParts(points: np.ndarray, min_points: int = 30, slab: float = 0.01,
                     max_parts: int = 3, min_length: float = 0.015) -> list[np.ndarray]:
    """Splits one branch instance into cylinder-like parts: points farther
    than ``max(3 r, r + 6 mm)`` from the fitted axis of the dominant part
    (e.g. a peduncle stalk labelled as branch) form further parts; those
    shorter than ``min_length`` (m) or 3 radii are dropped (a few points of
    a mostly hidden stalk give no reliable cylinder)."""
    parts, rest = [], np.asarray(points, float)
    while len(rest) >= 10 and len(parts) < max_parts:
        centre, axis, _, _, radius = EstimateCylinder(rest, slab)
        rel = rest - centre
        radial = np.linalg.norm(rel - (rel @ axis)[:, None] * axis, axis=1)
        inl = radial < max(3 * radius, radius + 0.006)
        parts.append(rest[inl])
        rest = rest[~inl]
        if len(rest) < min_points:
            break
    keep = []
    for i, p in enumerate(parts):
        if len(p) < 10:
            continue
        if i > 0:  # secondary parts: only clearly elongated ones (a stalk)
            _, _, s0, s1, r = EstimateCylinder(p, slab)
            if len(p) < min_points or s1 - s0 < max(min_length, 3 * r):
                continue
        keep.append(p)
    return keep


def CompleteBranches(points_W, instance, camera_W, params=None, min_points: int = 30,
                     max_points: int = 6000) -> BranchEstimate | None:
    """Completes every branch instance with at least ``min_points`` points
    (all points as one instance when ids are missing / all -1), each split
    into cylinder-like parts (``SplitBranchParts``: a peduncle stalk becomes
    its own cylinder), and merges the meshes; the axis is that of the
    largest part."""
    pts = np.asarray(points_W, float)
    if len(pts) < 10:
        return None
    inst = np.asarray(instance) if instance is not None and len(instance) == len(pts) \
        else -np.ones(len(pts), int)
    if len(pts) > max_points:  # fused clouds: a seeded subsample is plenty
        keep = np.sort(np.random.default_rng(0).choice(len(pts), max_points, replace=False))
        pts, inst = pts[keep], inst[keep]
    ids = [i for i in np.unique(inst) if i >= 0 and (inst == i).sum() >= min_points]
    groups = [pts[inst == i] for i in ids] if ids else [pts]
    parts = [p for g in groups for p in SplitBranchParts(g, min_points)]
    parts.sort(key=len, reverse=True)
    out = [CompleteBranch(g, camera_W, params) for g in parts]
    if not out:
        return None
    V, F, S, off = [], [], [], 0
    for b in out:
        V.append(b.vertices_W)
        F.append(b.faces + off)
        S.append(b.samples_W)
        off += len(b.vertices_W)
    return BranchEstimate(np.vstack(V), np.vstack(F), np.vstack(S), out[0].axis_W)
