"""Leaf geometry: a 2D blade + petiole outline, its triangulation, and a
two-layer tetrahedral mesh bent into 3D (metres).

Leaf coordinates: ``u`` runs along the midrib from the blade base (u = 0)
to the tip (u = length); the petiole occupies u in [-petiole_length, 0];
``v`` is the lateral coordinate (v = 0 on the midrib).
"""
from __future__ import annotations

import dataclasses as dc

import numpy as np
from matplotlib.path import Path as _MplPath
from scipy.spatial import Delaunay


@dc.dataclass
class LeafShape:
    """Blade outline and thickness (m). ``shape`` is 'ovate' (widest near the
    base) or 'elliptic' (widest in the middle)."""
    length: float = 0.12
    width: float = 0.065
    shape: str = "ovate"
    petiole_length: float = 0.03
    petiole_width: float = 0.006
    thickness: float = 0.002
    element_size: float = 0.008


def HalfWidth(shape: LeafShape, u: np.ndarray) -> np.ndarray:
    """Blade half-width at midrib coordinate ``u`` (0 outside the blade)."""
    t = np.clip(np.asarray(u, float) / shape.length, 0.0, 1.0)
    a, b = {"ovate": (0.6, 1.0), "elliptic": (1.0, 1.0)}[shape.shape]
    t_max = a / (a + b)
    peak = t_max ** a * (1 - t_max) ** b
    w = 0.5 * shape.width * (t ** a) * ((1 - t) ** b) / peak
    return np.maximum(w, 0.5 * shape.petiole_width * (t < 0.5))


def Outline(shape: LeafShape, spacing: float) -> np.ndarray:
    """Closed outline polygon (K, 2) of petiole + blade in (u, v), CCW."""
    if shape.shape not in ("ovate", "elliptic"):
        raise ValueError(f"leaf shape must be 'ovate' or 'elliptic', got {shape.shape!r}")
    n_blade = max(8, int(np.ceil(2.2 * shape.length / spacing)))
    u_blade = shape.length * (1 - np.cos(np.linspace(0, np.pi, n_blade))) / 2
    n_pet = max(2, int(np.ceil(shape.petiole_length / spacing)) + 1)
    u_pet = np.linspace(-shape.petiole_length, 0.0, n_pet)[:-1]
    hw_pet = 0.5 * shape.petiole_width
    right = np.concatenate([np.c_[u_pet, -np.full_like(u_pet, hw_pet)],
                            np.c_[u_blade, -HalfWidth(shape, u_blade)]])
    left = right[::-1].copy()
    left[:, 1] *= -1
    # right side base -> tip, then the left side tip -> base (tip once); the
    # polygon closes across the petiole's base.
    return np.concatenate([right, left[1:]])


def TriangulateLeaf(shape: LeafShape) -> tuple[np.ndarray, np.ndarray]:
    """Triangle mesh (uv (N, 2), faces (F, 3)) of the leaf outline with
    elements of about ``shape.element_size``."""
    return TriangulatePolygon(Outline(shape, shape.element_size), shape.element_size)


def TriangulatePolygon(poly: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Triangle mesh (points (N, 2), faces (F, 3)) of the closed polygon
    ``poly`` (K, 2) with elements of about ``h`` (the polygon's units): the
    boundary resampled at ``h``, a hexagonal grid inside, Delaunay, the
    triangles outside the polygon and the slivers dropped."""
    poly = np.asarray(poly, float)
    # Resample the boundary at spacing ~h.
    seg = np.diff(np.vstack([poly, poly[:1]]), axis=0)
    pts = [poly[i] + seg[i] * f for i in range(len(poly))
           for f in np.arange(0, 1, h / max(np.linalg.norm(seg[i]), 1e-9))]
    boundary = np.array(pts)
    # Drop boundary samples closer than 0.3 h to the previous kept one (the
    # resampling can put two almost on top of each other at short segments).
    keep = [0]
    for i in range(1, len(boundary)):
        if np.linalg.norm(boundary[i] - boundary[keep[-1]]) > 0.3 * h:
            keep.append(i)
    if np.linalg.norm(boundary[keep[-1]] - boundary[0]) <= 0.3 * h and len(keep) > 3:
        keep.pop()
    boundary = boundary[keep]
    # Interior: a hexagonal grid kept at least 0.45 h from the boundary.
    u0, u1 = poly[:, 0].min(), poly[:, 0].max()
    v0, v1 = poly[:, 1].min(), poly[:, 1].max()
    rows = np.arange(u0, u1 + h, h * np.sqrt(3) / 2)
    grid = [np.c_[np.full(len(vs), u), vs]
            for k, u in enumerate(rows)
            for vs in [np.arange(v0 + (h / 2) * (k % 2), v1, h)]]
    grid = np.vstack(grid)
    path = _MplPath(poly)
    inside = path.contains_points(grid)
    grid = grid[inside]
    if len(grid):
        d = np.min(np.linalg.norm(grid[:, None, :] - boundary[None, :, :], axis=2), axis=1)
        grid = grid[d > 0.45 * h]
    uv = np.vstack([boundary, grid])
    tri = Delaunay(uv)
    faces = tri.simplices
    centroids = uv[faces].mean(axis=1)
    keep = path.contains_points(centroids, radius=-1e-9) | path.contains_points(centroids)
    faces = faces[keep]
    # No slivers: drop triangles with almost no area (collinear boundary points).
    a, b = uv[faces[:, 1]] - uv[faces[:, 0]], uv[faces[:, 2]] - uv[faces[:, 0]]
    area = 0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    faces = faces[area > 0.02 * h * h]
    used = np.unique(faces)
    remap = -np.ones(len(uv), int)
    remap[used] = np.arange(len(used))
    return uv[used], remap[faces]


def ExtrudeToTets(uv: np.ndarray, faces: np.ndarray, layers: int = 2
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Layered prisms split into 3 tetrahedra each (conforming split by vertex
    index). Returns (nodes (N*(layers+1), 3) as (u, v, layer), tets (T, 4))."""
    n = len(uv)
    nodes = np.vstack([np.c_[uv, np.full(n, k)] for k in range(layers + 1)]).astype(float)
    tets = []
    sorted_faces = np.sort(faces, axis=1)
    for k in range(layers):
        lo, hi = k * n, (k + 1) * n
        a, b, c = sorted_faces[:, 0], sorted_faces[:, 1], sorted_faces[:, 2]
        tets.append(np.c_[a + lo, b + lo, c + lo, a + hi])
        tets.append(np.c_[b + lo, c + lo, a + hi, b + hi])
        tets.append(np.c_[c + lo, a + hi, b + hi, c + hi])
    return nodes, np.vstack(tets)


def OrientTets(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Reorders tets so that every signed volume is positive."""
    p = vertices[tets]
    vol = np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]),
                    p[:, 3] - p[:, 0])
    out = tets.copy()
    neg = vol < 0
    out[neg, 1], out[neg, 2] = tets[neg, 2], tets[neg, 1]
    return out


def TetVolumes(vertices: np.ndarray, tets: np.ndarray) -> np.ndarray:
    p = vertices[tets]
    return np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]),
                     p[:, 3] - p[:, 0]) / 6.0


def BoundaryTriangles(tets: np.ndarray) -> np.ndarray:
    """Outward-oriented surface triangles of a (positively oriented) tet mesh."""
    local = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
    tris = tets[:, local].reshape(-1, 3)
    key = np.sort(tris, axis=1).astype(np.int64)
    n = int(key.max()) + 1 if len(key) else 1
    # one integer per sorted triple (same order as the rows): a 1-D unique
    # is ~10x faster than np.unique(axis=0)
    key = (key[:, 0] * n + key[:, 1]) * n + key[:, 2]
    _, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    return tris[counts[inv.ravel()] == 1]


def TetMeshToVtk(vertices: np.ndarray, tets: np.ndarray) -> str:
    """Legacy ASCII VTK unstructured grid (cell type 10 = tetra)."""
    lines = ["# vtk DataFile Version 3.0", "leaf", "ASCII", "DATASET UNSTRUCTURED_GRID",
             f"POINTS {len(vertices)} double"]
    lines += [f"{x:.9g} {y:.9g} {z:.9g}" for x, y, z in vertices]
    lines.append(f"CELLS {len(tets)} {5 * len(tets)}")
    lines += [f"4 {a} {b} {c} {d}" for a, b, c, d in tets]
    lines.append(f"CELL_TYPES {len(tets)}")
    lines += ["10"] * len(tets)
    return "\n".join(lines) + "\n"


def _TetEdges(x: np.ndarray, tets: np.ndarray) -> np.ndarray:
    p = x[tets]
    return np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=2)


def RestShapeInverse(rest: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Per-tet Dm^-1 (T, 3, 3) of the rest edges, for ``MaxPrincipalStretch``
    of a mesh measured many times."""
    return np.linalg.inv(_TetEdges(rest, tets))


def MaxPrincipalStretch(rest: np.ndarray, current: np.ndarray, tets: np.ndarray,
                        Dm_inv: np.ndarray | None = None) -> np.ndarray:
    """Per-tet largest singular value of the deformation gradient F = Ds Dm^-1
    (the square root of F^T F's largest eigenvalue). ``Dm_inv``:
    ``RestShapeInverse(rest, tets)`` when already known."""
    if Dm_inv is None:
        Dm_inv = RestShapeInverse(rest, tets)
    F = _TetEdges(current, tets) @ Dm_inv
    return np.sqrt(np.linalg.eigvalsh(np.swapaxes(F, 1, 2) @ F)[:, -1])


def TurnHeldLeaf(points_W: np.ndarray, attach_W: np.ndarray, p_WG: np.ndarray,
                 axis_W: np.ndarray, angle: float, pull_W: np.ndarray | None = None,
                 bend_fraction: float = 0.35) -> tuple[np.ndarray, np.ndarray]:
    """A leaf as a gripper at ``p_WG`` holds it after turning it by ``angle``
    (rad) about the line through its petiole attachment ``attach_W`` along
    ``axis_W`` and moving it by ``pull_W`` (m, W): each point (N, 3, W, m)
    turns by ``angle`` x w and moves by ``pull_W`` x w, where w rises
    smoothly from 0 at the attachment to 1 at ``bend_fraction`` of the
    attachment-grasp distance along that line (the petiole and the blade's
    base bend, the rest of the blade turns as one piece). A twist is the
    attachment-grasp line as the axis, an arc an axis across it. For
    rendered training views of a held leaf (``scripts/make_segnet_data.py``),
    not a mechanical model. Returns (points (N, 3), R_W (3, 3): the turn at
    the grasp)."""
    from scipy.spatial.transform import Rotation
    p = np.asarray(points_W, float).reshape(-1, 3)
    a = np.asarray(attach_W, float).reshape(3)
    line = np.asarray(p_WG, float).reshape(3) - a
    length = float(np.linalg.norm(line))
    axis = np.asarray(axis_W, float).reshape(3)
    if length <= 1e-6 or np.linalg.norm(axis) <= 1e-9 or not 0 < bend_fraction <= 1:
        raise ValueError("TurnHeldLeaf needs a grasp away from the attachment, a nonzero "
                         "axis and bend_fraction in (0, 1]")
    axis = axis / np.linalg.norm(axis)
    s = np.clip(((p - a) @ (line / length)) / (bend_fraction * length), 0.0, 1.0)
    w = s * s * (3.0 - 2.0 * s)                      # smoothstep
    turned = Rotation.from_rotvec(np.outer(w * angle, axis)).apply(p - a) + a
    if pull_W is not None:
        turned = turned + np.outer(w, np.asarray(pull_W, float).reshape(3))
    return turned, Rotation.from_rotvec(angle * axis).as_matrix()
