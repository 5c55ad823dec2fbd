"""Leaves of plants from files (``plant_scene.kind: mesh_plant``) as
sheets: a flat 2D parameter domain (metres) with the leaf outline in it and
a map to the 3D surface. A textured card whose texture has transparent
pixels is cut to its alpha outline (the largest region of alpha at least
the threshold, within the part of the texture the card covers, traced in
texture space and mapped onto the card); any other leaf is its surface
projected on its best-fit plane, the outline its boundary (a closed,
two-sided leaf: its side facing the plane normal; a leaf folding over the
plane: not ``flat``, used as its own triangles)."""
from __future__ import annotations

import dataclasses as dc

import contourpy
import numpy as np
import trimesh

ALPHA_SIDE = 256                 # px: alpha masks are read at most this large


@dc.dataclass
class LeafSheet:
    """A leaf as a sheet: ``outline`` (K, 2) in a flat parameter domain
    (m), the source triangles (``V`` (N, 3) P or W frame, m; ``F``) and
    their parameter coordinates ``param`` (N, 2); ``tex_scale`` (2,): for a
    card, texture uv = param / tex_scale (None otherwise). ``flat``: the
    parameter map is one-to-one (no face flips over in it); a folded leaf
    is not, and is used as its source triangles (``area``: theirs)."""
    outline: np.ndarray
    V: np.ndarray
    F: np.ndarray
    param: np.ndarray
    tex_scale: np.ndarray | None = None
    flat: bool = True

    @property
    def area(self) -> float:
        if not self.flat:
            return float(trimesh.Trimesh(self.V, self.F, process=False).area)
        x, y = self.outline[:, 0], self.outline[:, 1]
        return float(0.5 * abs(x @ np.roll(y, -1) - y @ np.roll(x, -1)))

    def Map(self, q: np.ndarray, values: np.ndarray | None = None) -> np.ndarray:
        """Per-vertex ``values`` (default: the 3D positions ``V``)
        interpolated at parameter points ``q`` (M, 2): barycentric in the
        source triangle holding the point (the nearest one, clamped, for a
        point outside all)."""
        values = self.V if values is None else values
        A, B, C = (self.param[self.F[:, k]] for k in range(3))
        e0, e1 = B - A, C - A
        det = e0[:, 0] * e1[:, 1] - e0[:, 1] * e1[:, 0]
        det = np.where(np.abs(det) < 1e-18, 1e-18, det)
        out = []
        for s in range(0, len(q), 256):
            d = q[s:s + 256, None, :] - A[None]
            b1 = (d[..., 0] * e1[None, :, 1] - d[..., 1] * e1[None, :, 0]) / det
            b2 = (e0[None, :, 0] * d[..., 1] - e0[None, :, 1] * d[..., 0]) / det
            bary = np.stack([1 - b1 - b2, b1, b2], -1)
            f = np.argmax(bary.min(-1), axis=1)
            w = np.clip(bary[np.arange(len(f)), f], 0, None)
            w /= np.maximum(w.sum(1, keepdims=True), 1e-12)
            out.append(np.einsum("mk,mkd->md", w, values[self.F[f]]))
        return np.vstack(out) if out else np.zeros((0, values.shape[1]))

    def Transformed(self, X: np.ndarray) -> "LeafSheet":
        """The sheet moved by the 4x4 rigid transform ``X``."""
        return dc.replace(self, V=self.V @ X[:3, :3].T + X[:3, 3])


def AlphaOutline(image, uv_box, threshold: float) -> np.ndarray | None:
    """The outline (K, 2, texture uv, v up) of the largest region of alpha
    at least ``threshold`` within ``uv_box`` ((u0, v0), (u1, v1): the part of
    the texture the card covers; a leaf atlas holds many), or None if that
    part has no transparent pixel (not a cut-out card)."""
    (u0, v0), (u1, v1) = np.clip(uv_box, 0.0, 1.0)
    W, H = image.size
    box = (int(np.floor(u0 * W)), int(np.floor((1 - v1) * H)),
           max(int(np.ceil(u1 * W)), int(np.floor(u0 * W)) + 1),
           max(int(np.ceil((1 - v0) * H)), int(np.floor((1 - v1) * H)) + 1))
    im = image.crop(box)
    if max(im.size) > ALPHA_SIDE:
        f = ALPHA_SIDE / max(im.size)
        im = im.resize((max(2, int(im.size[0] * f)), max(2, int(im.size[1] * f))))
    a = np.asarray(im.getchannel("A"), float) / 255.0
    if a.min() >= threshold:
        return None
    h, w = a.shape
    best, best_area = None, 0.0
    for ln in contourpy.contour_generator(z=np.pad(a, 1)).lines(threshold):
        if len(ln) < 4:
            continue
        x, y = ln[:, 0], ln[:, 1]
        area = 0.5 * abs(x @ np.roll(y, -1) - y @ np.roll(x, -1))
        if area > best_area:
            best, best_area = ln, area
    if best is None:
        return np.zeros((0, 2))
    # pixel centres (padding removed) -> texture uv
    u = (box[0] + (best[:, 0] - 0.5) / w * (box[2] - box[0])) / W
    v = 1.0 - (box[1] + (best[:, 1] - 0.5) / h * (box[3] - box[1])) / H
    pts = np.c_[u, v]
    return pts[:-1] if np.allclose(pts[0], pts[-1]) else pts


def CardSheet(V, F, uv, image, threshold: float) -> LeafSheet | None:
    """The cut-out sheet of a textured card (triangles ``V`` (N, 3), ``F``,
    texture ``uv`` (N, 2), RGBA PIL ``image``) with an alpha outline, else None."""
    if image is None or uv is None or "A" not in image.getbands():
        return None
    outline_uv = AlphaOutline(image, (uv.min(0), uv.max(0)), threshold)
    if outline_uv is None:
        return None
    V, F = np.asarray(V, float), np.asarray(F)
    # metres per texture unit along u and v (the card's affine maps, area weighted)
    e_u, e_v, wsum = np.zeros(2), np.zeros(2), 0.0
    for f in F:
        duv = np.c_[uv[f[1]] - uv[f[0]], uv[f[2]] - uv[f[0]]]
        dP = np.c_[V[f[1]] - V[f[0]], V[f[2]] - V[f[0]]]
        if abs(np.linalg.det(duv)) < 1e-12:
            continue
        J = dP @ np.linalg.inv(duv)                 # (3, 2): dP/du, dP/dv
        area = 0.5 * float(np.linalg.norm(np.cross(dP[:, 0], dP[:, 1])))
        e_u += area * np.array([np.linalg.norm(J[:, 0]), 1.0])
        e_v += area * np.array([np.linalg.norm(J[:, 1]), 1.0])
        wsum += area
    if wsum <= 0:                  # texture coordinates spanning no area: not a card
        return None
    scale = np.array([e_u[0] / e_u[1], e_v[0] / e_v[1]])
    return LeafSheet(outline=outline_uv * scale, V=V, F=F, param=uv * scale, tex_scale=scale)


def BoundaryLoop(mesh: trimesh.Trimesh) -> np.ndarray:
    """The vertex indices of the longest boundary loop of an open mesh."""
    edges = mesh.edges_sorted
    single = trimesh.grouping.group_rows(edges, require_count=1)
    if not len(single):
        return np.zeros(0, int)
    nxt: dict = {}
    for a, b in edges[single]:
        nxt.setdefault(int(a), []).append(int(b))
        nxt.setdefault(int(b), []).append(int(a))
    seen, best = set(), []
    for start in nxt:
        if start in seen:
            continue
        loop, prev, cur = [start], None, start
        seen.add(start)
        while True:
            options = [x for x in nxt[cur] if x != prev and x not in seen]
            if not options:
                break
            prev, cur = cur, options[0]
            seen.add(cur)
            loop.append(cur)
        if len(loop) > len(best):
            best = loop
    return np.asarray(best, int)


def SurfaceSheet(mesh: trimesh.Trimesh) -> LeafSheet:
    """A leaf surface as a sheet: projected on its best-fit plane; a closed
    (two-sided) surface keeps the faces facing the plane normal."""
    m = trimesh.Trimesh(np.asarray(mesh.vertices, float), np.asarray(mesh.faces),
                        process=False)
    m.merge_vertices()
    m.update_faces(m.nondegenerate_faces())
    m.remove_unreferenced_vertices()
    if len(m.faces) == 0:
        return LeafSheet(np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 3), int),
                         np.zeros((0, 2)))
    c = m.vertices.mean(0)
    _, _, Vt = np.linalg.svd(m.vertices - c, full_matrices=False)
    e1, e2, n = Vt[0], Vt[1], Vt[2]
    if m.is_watertight or not len(BoundaryLoop(m)):
        up = m.face_normals @ n >= 0
        m = m.submesh([up], append=True) if up.any() else m
    param = np.c_[(m.vertices - c) @ e1, (m.vertices - c) @ e2]
    loop = BoundaryLoop(m)
    outline = param[loop] if len(loop) >= 3 else np.zeros((0, 2))
    a, b, d = (param[m.faces[:, k]] for k in range(3))
    signed = (b - a)[:, 0] * (d - a)[:, 1] - (b - a)[:, 1] * (d - a)[:, 0]
    flips = min((signed > 0).sum(), (signed < 0).sum())
    sheet = LeafSheet(outline=outline, V=np.asarray(m.vertices), F=np.asarray(m.faces),
                      param=param)
    sheet.flat = bool(flips == 0 and sheet.area >= 0.97 * 0.5 * np.abs(signed).sum())
    return sheet
