"""A plant from mesh files (``plant_scene.kind: mesh_plant``) as a plant
model: the parts read by ``mesh_plant_files`` placed in the world by
``mesh_plant.X_W_plant``, fruit ground truth from the fruit meshes, and the
leaves near the target fruits made FEM slabs. World frame W, metres.

* Stems: welded meshes; each also a ``Branch`` (a centre line through the
  mesh along its main axis, radius the median vertex distance to it) for
  ground truth and collision (cylinders along it).
* Fruits: the repaired closed mesh; centre = volume centroid, volume, and
  the peduncle axis from the centroid to the mean of the stem points inside
  the fruit (or, if none, within 0.5 mm of the closest one, if that is
  within 3 mm): where the stalk enters; +z of W when no stem touches it.
* Leaves: indices as the greenhouse plant (FEM leaves first, then the
  static ones). camera0's occlusion of each target by each leaf picks the
  FEM leaves (``greenhouse._ChooseFem``: the targets' occluders, most hiding
  first, then the leaves within ``fem_radius``; never a leaf within half a
  slab of a fruit). An FEM leaf is the leaf's outline retriangulated at the
  element size of ``fem_target_tets``, mapped onto its surface (a leaf
  folded over its best-fit plane: its own triangles) and extruded
  along the surface normal into two tet layers ``plant_scene.leaf.thickness``
  thick (``leaf.ExtrudeToTets``); fixed at the nodes within max(4 mm, 1.2
  elements) of its point nearest a stem (the petiole end, or the manifest's
  ``attach``). Its leaf coordinates run from there (u, to the farthest
  point) and across (v).
"""
from __future__ import annotations

import dataclasses as dc
from types import SimpleNamespace

import numpy as np
import trimesh
from pydrake.geometry import Rgba
from pydrake.math import RotationMatrix
from scipy.spatial import cKDTree

from lmap_drake.plants.greenhouse import _ChooseFem
from lmap_drake.plants.greenhouse_model import GreenhousePlantModel, StaticLeaf
from lmap_drake.plants.leaf import ExtrudeToTets, OrientTets, TriangulatePolygon
from lmap_drake.plants.mesh_plant_files import (MeshPart, MeshPlantError, LoadMeshPlantParts,
                                                TargetFruits)
from lmap_drake.plants.multi import OCCLUDER_MIN, Branch, MultiFruit, MultiLeaf
from lmap_drake.plants.multi_geometry import FruitView, SurfaceDistance

TOUCH = 0.003           # m: a stem this close to a fruit (or inside it) is its stalk
SKELETON_BINS = 8


@dc.dataclass
class PartVisual:
    """A part's render mesh (W, m) with its texture (``uv`` per vertex and
    an RGBA PIL ``image``) or colour (RGBA 0-1)."""
    mesh: trimesh.Trimesh
    color: tuple
    uv: np.ndarray | None = None
    image: object = None


@dc.dataclass
class MeshStaticLeaf(StaticLeaf):
    """A welded leaf of a file plant: ``StaticLeaf`` plus its render
    visual and source file."""
    visual: PartVisual | None = None
    source: str = ""


@dc.dataclass
class MeshPlantModel(GreenhousePlantModel):
    """A plant from files: as a ``GreenhousePlantModel`` (``leaves`` the FEM
    leaves, ``static_leaves`` the rest, ``branches`` one per stem part),
    plus the stems' and fruits' visuals and each part's source file."""
    stem_visuals: list = dc.field(default_factory=list)
    fruit_visuals: list = dc.field(default_factory=list)
    fruit_names: list = dc.field(default_factory=list)
    leaf_sources: list = dc.field(default_factory=list)   # FEM leaves', in leaf order

    def GroundTruthDict(self) -> dict:
        d = super().GroundTruthDict()
        d["kind"] = "mesh_plant"
        for f, name in zip(d["fruits"], self.fruit_names):
            f["name"] = name
        sources = list(self.leaf_sources) + [s.source for s in self.static_leaves]
        for lf, src in zip(d["leaves"], sources):
            lf["source"] = src
        return d


def _Rgba(c) -> Rgba:
    return c if isinstance(c, Rgba) else Rgba(*c)


def _Skeleton(V: np.ndarray) -> tuple[np.ndarray, float]:
    """A centre line (K, 3) through points along their main axis, and the
    median distance of the points to it (m)."""
    c = V.mean(0)
    axis = np.linalg.svd(V - c, full_matrices=False)[2][0]
    t = (V - c) @ axis
    edges = np.linspace(t.min(), t.max(), SKELETON_BINS + 1)
    pts = []
    for k in range(SKELETON_BINS):
        sel = (t >= edges[k]) & (t <= edges[k + 1])
        if sel.any():
            pts.append(V[sel].mean(0))
    pts = np.array(pts) if len(pts) >= 2 else np.array([c + axis * t.min(), c + axis * t.max()])
    seg = np.linspace(0, 1, 8)[:, None]
    dense = np.vstack([pts[k] + seg * (pts[k + 1] - pts[k]) for k in range(len(pts) - 1)])
    r = float(np.median(cKDTree(dense).query(V)[0]))
    return pts, max(r, 5e-4)


def _TexColor(part: MeshPart, fallback) -> tuple:
    """The part's colour: its own, else its texture's mean opaque colour, else ``fallback``."""
    if part.color is not None:
        return tuple(part.color)
    if part.image is not None:
        a = np.asarray(part.image.resize((32, 32)), float) / 255.0
        w = a[..., 3] > 0.5
        if w.any():
            return tuple(a[w, :3].mean(0)) + (1.0,)
    return tuple(_Rgba(fallback).rgba)


def _Fruit(i, part, X, stem_pts, stem_owner, color) -> MultiFruit:
    mesh = part.mesh.copy().apply_transform(X)
    c = np.asarray(mesh.center_mass, float)
    d = SurfaceDistance([mesh], stem_pts)
    # the stalk: the stem points inside the fruit, or those touching it
    touch = d <= max(float(d.min()), 0.0) + 5e-4
    if d.min() <= TOUCH:
        top = stem_pts[touch].mean(0)
        axis = top - c
        shoot = int(np.bincount(stem_owner[touch]).argmax())
    else:
        axis = np.array([0.0, 0.0, 1.0])
        shoot = int(stem_owner[int(np.argmin(d))])
    axis = axis / max(float(np.linalg.norm(axis)), 1e-12)
    tip = c + axis * float(np.max((mesh.vertices - c) @ axis))
    X_WO = np.eye(4)
    X_WO[:3, :3] = RotationMatrix.MakeFromOneVector(axis, 2).matrix()
    X_WO[:3, 3] = c
    return MultiFruit(mesh_W=mesh, stripe_faces=np.zeros(len(mesh.faces), bool), X_WO=X_WO,
                      center_W=c, peduncle_axis_W=axis, peduncle_tip_W=tip,
                      stalk_W=np.array([tip, tip]), volume=float(mesh.volume), shoot=shoot,
                      color=_Rgba(color), stripe_color=_Rgba(color), stalk_radius=0.003,
                      fruit_file=part.source, fruit_mesh_repairs=list(part.repairs))


def _LeafSurface(part: MeshPart, X) -> tuple:
    """(surface W, sheet W, texture uv or None): a card's cut-out surface, else the file's."""
    sheet = part.sheet.Transformed(X)
    if part.card:
        h = float(np.sqrt(sheet.area)) / 12.0
        q, F = TriangulatePolygon(sheet.outline, h)
        return trimesh.Trimesh(sheet.Map(q), F, process=False), sheet, q / sheet.tex_scale
    return part.mesh.copy().apply_transform(X), sheet, part.uv


def FemLeafSlab(sheet, attach_W, normal_W, thickness: float, target_tets: int,
                shoot: int) -> MultiLeaf:
    """The FEM slab of a leaf sheet (W; see the module docstring); a folded
    leaf's (``sheet.flat`` false) from its own triangles."""
    h = float(np.sqrt(13.86 * sheet.area / target_tets))
    if sheet.flat:
        q, F = TriangulatePolygon(sheet.outline, h)
        P = sheet.Map(q)
    else:
        q, F, P = sheet.param, sheet.F, sheet.V
    surf = trimesh.Trimesh(P, F, process=False)
    trimesh.repair.fix_winding(surf)
    F = np.asarray(surf.faces)
    vn = np.array(surf.vertex_normals, float)
    if vn.sum(0) @ normal_W < 0:                 # the upper layer toward the camera
        vn = -vn
    nodes, tets = ExtrudeToTets(q, F, layers=2)
    n = len(q)
    offset = (nodes[:, 2] - 1.0) * 0.5 * thickness           # layers 0, 1, 2: below, mid, above
    rest = np.tile(P, (3, 1)) + offset[:, None] * np.tile(vn, (3, 1))
    tets = OrientTets(rest, tets)
    a = P[int(np.argmin(np.linalg.norm(P - attach_W, axis=1)))]
    fixed = np.linalg.norm(rest - a, axis=1) <= max(0.004, 1.2 * h)
    if fixed[:n].sum() < 3:
        near = np.argsort(np.linalg.norm(P - a, axis=1))[:3]
        fixed[np.r_[near, near + n, near + 2 * n]] = True
    far = P[int(np.argmax(np.linalg.norm(P - a, axis=1)))]
    e_mid = (far - a) / max(float(np.linalg.norm(far - a)), 1e-12)
    e_lat = np.cross(normal_W, e_mid)
    e_lat /= max(float(np.linalg.norm(e_lat)), 1e-12)
    uv = np.c_[(rest - a) @ e_mid, (rest - a) @ e_lat]
    return MultiLeaf(rest_W=rest, tets=tets, uv=uv, fixed=fixed, attach_W=a, shoot=shoot,
                     fruit=-1, midrib_W=e_mid, normal_W=np.asarray(normal_W, float),
                     swing_deg=0.0, reach=0.0)


def BuildMeshPlant(cfg, p_WC) -> MeshPlantModel:
    """The ``MeshPlantModel`` of ``cfg`` (a ``PlantSceneConfig`` with ``kind:
    mesh_plant``) seen by camera0 at ``p_WC`` (m, W). Raises MeshPlantError
    (naming the key and file) for bad files."""
    mp = cfg.mesh_plant
    parts = LoadMeshPlantParts(mp)
    target_idx = TargetFruits(parts, mp)
    p_WC = np.asarray(p_WC, float)
    X = mp.X_W_plant.GetRigidTransform().GetAsMatrix4()
    stems = [p for p in parts if p.kind == "stem"]
    fruit_parts = [p for p in parts if p.kind == "fruit"]
    leaf_parts = [p for p in parts if p.kind == "leaf"]
    branches, stem_visuals, samples, owner = [], [], [], []
    for b, p in enumerate(stems):
        m = p.mesh.copy().apply_transform(X)
        pts, r = _Skeleton(np.asarray(m.vertices))
        branches.append(Branch(p.name, pts, r, -1))
        stem_visuals.append(PartVisual(m, _TexColor(p, cfg.branch.color), p.uv, p.image))
        s = np.vstack([m.vertices, trimesh.sample.sample_surface_even(m, 400, seed=0)[0]])
        samples.append(s)
        owner.append(np.full(len(s), b))
    stem_pts, stem_owner = np.vstack(samples), np.concatenate(owner)
    stem_tree = cKDTree(stem_pts)
    fruits, fruit_visuals = [], []
    for i, p in enumerate(fruit_parts):
        color = _TexColor(p, mp.fruit_color)
        fruits.append(_Fruit(i, p, X, stem_pts, stem_owner, color))
        textured = p.uv is not None and p.image is not None
        fruit_visuals.append(PartVisual(p.render.copy().apply_transform(X), color, p.uv, p.image)
                             if textured else PartVisual(fruits[-1].mesh_W, color))
    stem_meshes = [v.mesh for v in stem_visuals]
    views = [FruitView(f.mesh_W, [g.mesh_W for k, g in enumerate(fruits) if k != i]
                       + stem_meshes, p_WC) for i, f in enumerate(fruits)]
    surfs, sheets, texuv, attach, shoot, normal = [], [], [], [], [], []
    for p in leaf_parts:
        surf, sheet, uv = _LeafSurface(p, X)
        surfs.append(surf)
        sheets.append(sheet)
        texuv.append(uv)
        if p.attach is not None:
            a = X[:3, :3] @ p.attach + X[:3, 3]
        else:
            a = surf.vertices[int(np.argmin(stem_tree.query(surf.vertices)[0]))]
        attach.append(np.asarray(a, float))
        shoot.append(int(stem_owner[stem_tree.query(a)[1]]))
        n = (surf.face_normals * surf.area_faces[:, None]).sum(0)
        if np.linalg.norm(n) < 1e-12:
            n = np.linalg.svd(surf.vertices - surf.vertices.mean(0))[2][2]
        n = n / np.linalg.norm(n)
        normal.append(n if n @ (p_WC - surf.vertices.mean(0)) >= 0 else -n)
    occluders = []
    for i in range(len(fruits)):
        single = np.array([views[i].Occlusion([s]) for s in surfs])
        occluders.append([int(j) for j in np.argsort(-single) if single[j] >= OCCLUDER_MIN])
    half = 0.5 * cfg.leaf.thickness + 0.001
    blocked = {j for j, s in enumerate(surfs)
               if float(SurfaceDistance([f.mesh_W for f in fruits], s.vertices).min()) < half}
    fem = _ChooseFem(SimpleNamespace(max_fem_leaves=mp.max_fem_leaves, fem_radius=mp.fem_radius,
                                     fem_occluders=False),
                     target_idx, occluders, fruits, surfs, blocked)
    order = fem + [j for j in range(len(leaf_parts)) if j not in fem]
    new_index = {j: k for k, j in enumerate(order)}
    for i, f in enumerate(fruits):
        f.occlusion_predicted = views[i].Occlusion(surfs)
        f.occluders = sorted(new_index[j] for j in occluders[i])
        f.one_leaf_ceiling = max(
            [1.0 - views[i].Occlusion([s for k, s in enumerate(surfs) if k != j])
             for j in occluders[i]] or [1.0 - f.occlusion_predicted])
    colors = [_TexColor(p, cfg.leaf.color) for p in leaf_parts]
    leaves = []
    for j in fem:
        leaves.append(FemLeafSlab(sheets[j], attach[j], normal[j], cfg.leaf.thickness,
                                  mp.fem_target_tets, shoot[j]))
    static = [MeshStaticLeaf(surface_W=surfs[j], attach_W=attach[j], shoot=shoot[j],
                             normal_W=normal[j], color=colors[j], color_below=colors[j],
                             visual=PartVisual(surfs[j], colors[j], texuv[j],
                                               leaf_parts[j].image),
                             source=leaf_parts[j].source) for j in order[len(fem):]]
    return MeshPlantModel(
        branches=branches, fruits=fruits, leaves=leaves, p_WC=p_WC, static_leaves=static,
        targets=target_idx, leaf_colors=[(colors[j], colors[j]) for j in fem], strings_W=[],
        num_stems=len(stems), stem_visuals=stem_visuals, fruit_visuals=fruit_visuals,
        fruit_names=[p.name for p in fruit_parts],
        leaf_sources=[leaf_parts[j].source for j in fem])


__all__ = ["BuildMeshPlant", "FemLeafSlab", "MeshPlantError", "MeshPlantModel",
           "MeshStaticLeaf", "PartVisual"]
