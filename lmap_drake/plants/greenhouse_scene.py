"""Adds a greenhouse plant (``plant_scene.kind: greenhouse``) and its
greenhouse dressing to the station's MultibodyPlant: stems, shoots and
fruits as the multi-fruit plant (``scene.AddMultiPlant``), the FEM leaves
(own colours), the static leaves (welded, two-tone: upper and lower side;
with ``greenhouse.textures`` every leaf and fruit textured instead, see
``leaf_texture``),
the strings, and static dressing (heating pipes, rails, a slab, a bright
glass wall, optionally a neighbouring row). Dressing is visual only and
labelled background (render label 0); the neighbouring row's leaves and
stems carry the neighbour labels (``labels.EncodeNeighbourLabel``:
background to the label oracle and scoring, leaf / branch to training)."""
from __future__ import annotations

import dataclasses as dc

import numpy as np
import trimesh
from pydrake.geometry import Box, CollisionFilterDeclaration, Cylinder, GeometrySet, Rgba
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant

from lmap_drake.labels import BRANCH, LEAF, EncodeLabel, EncodeNeighbourLabel
from lmap_drake.plants.leaf_texture import FruitTextureFiles, InsideTets, LeafTextureFiles
from lmap_drake.plants.multi_geometry import BranchTube
from lmap_drake.plants.config import PlantSceneConfig
from lmap_drake.plants.scene import (AddFemLeaf, AddMultiPlant, LeafBodyName,
                                     RegisterLabeledGeometry, RegisterTexturedVisual,
                                     _CylinderBetween, _ObjMesh)

STRING_RADIUS = 0.0012
STRING_COLOR = Rgba(0.92, 0.9, 0.82, 1.0)
PIPE_COLOR = Rgba(0.78, 0.8, 0.82, 1.0)
RAIL_COLOR = Rgba(0.45, 0.47, 0.5, 1.0)
SLAB_COLOR = Rgba(0.93, 0.93, 0.9, 1.0)
GLASS_COLOR = Rgba(0.82, 0.9, 0.97, 1.0)
ROW_COLOR = Rgba(0.2, 0.42, 0.16, 1.0)


def _Visual(plant, name: str, X: RigidTransform, shape, rgba: Rgba, label: int = 0) -> None:
    """Visual-only world geometry, render label ``label`` (background)."""
    RegisterLabeledGeometry(plant, plant.world_body(), X, shape, name, rgba, label,
                            collision=False)


def LeafTexturePaths(g, index: int, color, surface: trimesh.Trimesh, uv, normal_W):
    """(OBJ path, PNG path) of leaf ``index``'s textured surface, or None
    (``g.textures`` off, or no leaf coordinates)."""
    if not g.textures or uv is None:
        return None
    return LeafTextureFiles(g.seed, index, color, surface.vertices, surface.faces, uv, normal_W)


def _EmbeddedSurface(leaf) -> trimesh.Trimesh:
    """A FEM leaf's surface as its embedded render mesh: its vertices a
    hair inside the tetrahedra (``InsideTets``)."""
    surface = leaf.Surface()
    return trimesh.Trimesh(InsideTets(leaf.rest_W, leaf.tets), surface.faces, process=False)


def _RgbTuple(c) -> tuple:
    return (c.r(), c.g(), c.b()) if isinstance(c, Rgba) else tuple(c)[:3]


def _Rgba(c) -> Rgba:
    return Rgba(*c) if not isinstance(c, Rgba) else c


def UpperLowerSides(surface: trimesh.Trimesh, normal: np.ndarray):
    """The leaf surface's faces facing ``normal`` (upper side) and the rest."""
    up = surface.face_normals @ np.asarray(normal) >= 0
    return (surface.submesh([up], append=True) if up.any() else None,
            surface.submesh([~up], append=True) if (~up).any() else None)


def AddGreenhousePlant(plant: MultibodyPlant, scene_graph, model, cfg: PlantSceneConfig,
                       with_leaves: bool = True) -> dict:
    """Adds a ``GreenhousePlantModel``; handles as ``AddMultiPlant`` (FEM
    leaves ``leaf_<j>``). FEM leaves collide with the fruits and the robot,
    not with the stems, shoots or static leaves (their petioles sit inside
    the stems; static leaves would pin them). Static leaf ``s`` is labelled
    ``EncodeLabel(LEAF, len(model.leaves) + s)``."""
    g = cfg.greenhouse
    fruit_texture = None
    if g.textures:
        def fruit_texture(i, f, mesh):
            return FruitTextureFiles(g.seed, i, _RgbTuple(f.color), mesh, f.X_WO)
    handles = AddMultiPlant(plant, scene_graph, model, cfg, with_leaves=False,
                            fruit_texture=fruit_texture)
    world = plant.world_body()
    for s, pts in enumerate(model.strings_W):
        for k in range(len(pts) - 1):
            X, length = _CylinderBetween(pts[k] + [0.0, 0.0, 0.0], pts[k + 1])
            RegisterLabeledGeometry(plant, world, X, Cylinder(STRING_RADIUS, length),
                                    f"string_{s}_{k}", STRING_COLOR, EncodeLabel(BRANCH, s),
                                    collision=False)
    if g.dressing:
        AddGreenhouseDressing(plant, np.asarray(cfg.p_W_branch_base, float),
                              np.asarray(model.p_WC, float),
                              CanopyMesh(model) if g.neighbour_row else None)
    if not with_leaves:
        return handles
    K = len(model.leaves)
    static_gids = []
    for s, lf in enumerate(model.static_leaves):
        tex = LeafTexturePaths(g, K + s, lf.color, lf.surface_W, lf.uv, lf.normal_W)
        if tex is not None:
            RegisterTexturedVisual(plant, world, f"static_leaf_{s}", *tex, _Rgba(lf.color),
                                   EncodeLabel(LEAF, K + s))
        upper, lower = UpperLowerSides(lf.surface_W, lf.normal_W) if tex is None else (None,
                                                                                        None)
        for part, color, tag in ((upper, lf.color, "upper"), (lower, lf.color_below, "lower")):
            if part is not None:
                RegisterLabeledGeometry(plant, world, RigidTransform(),
                                        _ObjMesh(part, f"static_leaf_{s}_{tag}"),
                                        f"static_leaf_{s}_{tag}", _Rgba(color),
                                        EncodeLabel(LEAF, K + s), collision=False)
        if g.static_leaf_collision:
            static_gids.append(plant.RegisterCollisionGeometry(
                world, RigidTransform(), _ObjMesh(lf.surface_W, f"static_leaf_{s}_collision"),
                f"static_leaf_{s}_collision", CoulombFriction(0.8, 0.8)))
    cfm = scene_graph.collision_filter_manager()
    plant_rigid = [gid for gids in handles["branch_geometry_ids"] for gid in gids] + static_gids
    for j, leaf in enumerate(model.leaves):
        color = model.leaf_colors[j][0] if model.leaf_colors else cfg.leaf.color
        bid, gid = AddFemLeaf(plant, LeafBodyName(True, j), leaf.rest_W, leaf.tets, leaf.fixed,
                              dc.replace(cfg.leaf, color=_Rgba(color)), EncodeLabel(LEAF, j),
                              texture=LeafTexturePaths(g, j, color, _EmbeddedSurface(leaf),
                                                       leaf.uv, leaf.normal_W))
        handles["leaf_body_ids"].append(bid)
        handles["leaf_geometry_ids"].append(gid)
        if plant_rigid:
            cfm.Apply(CollisionFilterDeclaration().ExcludeBetween(
                GeometrySet(gid), GeometrySet(plant_rigid)))
    if handles["leaf_geometry_ids"] and not cfg.multi.leaf_leaf_contact:
        cfm.Apply(CollisionFilterDeclaration().ExcludeWithin(
            GeometrySet(handles["leaf_geometry_ids"])))
    return handles


def CanopyMesh(model) -> tuple[trimesh.Trimesh, trimesh.Trimesh]:
    """The plant's leaves and its stems, one mesh each (W): the neighbouring
    row's plants."""
    leaves = [s.surface_W for s in model.static_leaves] + [lf.Surface() for lf in model.leaves]
    return (trimesh.util.concatenate(leaves),
            trimesh.util.concatenate([BranchTube(b, sections=6) for b in model.branches]))


# The neighbouring plants, (along, toward the camera) from the plant's base
# (m): three in the next row behind, two beside it in its own row.
NEIGHBOUR_ROW = ((-0.5, -0.75), (0.0, -0.8), (0.5, -0.75), (-0.45, 0.0), (0.45, 0.0))


def RowFrame(base: np.ndarray, p_WC: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(along the row, toward the camera): horizontal unit vectors (W) of
    the row through ``base`` seen from ``p_WC``; (row, toward, z) is
    right-handed."""
    to_cam = np.asarray(p_WC, float) - np.asarray(base, float)
    d = np.array([to_cam[0], to_cam[1], 0.0])
    d /= max(np.linalg.norm(d), 1e-9)
    return np.cross(d, [0, 0, 1.0]), d


def NeighbourBases(base: np.ndarray, p_WC: np.ndarray) -> np.ndarray:
    """(5, 3) the neighbouring plants' bases (W, m) for a plant at ``base``
    seen from ``p_WC`` (``NEIGHBOUR_ROW``)."""
    row, d = RowFrame(base, p_WC)
    return np.array([np.asarray(base, float) + a * row + t * d for a, t in NEIGHBOUR_ROW])


def AddGreenhouseDressing(plant, base: np.ndarray, p_WC: np.ndarray,
                          canopy: tuple[trimesh.Trimesh, trimesh.Trimesh] | None) -> None:
    """Static greenhouse dressing around a plant at ``base`` seen from
    ``p_WC`` (W, m): a stone-wool slab on a hanging gutter under the row, two
    heating pipes (the pipe-rail) along the row, a wire above, a glass wall
    behind and, with ``canopy`` (a plant's leaf and stem meshes, W), a
    neighbouring row of shifted, turned copies of it beside and further back
    (neighbour labels: ``EncodeNeighbourLabel``)."""
    row, d = RowFrame(base, p_WC)
    R = RotationMatrix(np.c_[row, d, [0, 0, 1.0]])

    def at(along, toward, z):                 # a point in row coordinates
        return base + along * row + toward * d + np.array([0, 0, z])
    slab_top = base[2] - 0.005
    _Visual(plant, "gh_slab", RigidTransform(R, at(0, 0, -0.045) + [0, 0, slab_top - base[2]]),
            Box(1.6, 0.18, 0.08), SLAB_COLOR)
    _Visual(plant, "gh_gutter", RigidTransform(R, at(0, 0, -0.1)), Box(1.8, 0.26, 0.03),
            RAIL_COLOR)
    for k, off in enumerate((-0.3, 0.3)):           # pipe-rail: heating pipes either side
        for tag, zz in (("pipe", -0.12),):
            X = RigidTransform(RotationMatrix.MakeFromOneVector(row, 2), at(0, off, zz))
            _Visual(plant, f"gh_{tag}_{k}", X, Cylinder(0.026, 2.4), PIPE_COLOR)
    X = RigidTransform(RotationMatrix.MakeFromOneVector(row, 2), at(0, 0, 1.35))
    _Visual(plant, "gh_wire", X, Cylinder(0.002, 2.4), RAIL_COLOR)
    _Visual(plant, "gh_glass", RigidTransform(R, at(0, -1.6, 0.8)), Box(4.0, 0.02, 3.0),
            GLASS_COLOR)
    for k in range(-4, 5):                            # glasshouse posts
        _Visual(plant, f"gh_post_{k}", RigidTransform(R, at(0.5 * k, -1.58, 0.8)),
                Box(0.03, 0.03, 3.0), RAIL_COLOR)
    if canopy is not None:
        rng = np.random.default_rng(0)
        for k, (along, back) in enumerate(NEIGHBOUR_ROW):
            c = np.clip(np.array([ROW_COLOR.r(), ROW_COLOR.g(), ROW_COLOR.b()])
                        * rng.uniform(0.8, 1.2), 0, 1)
            turn = RotationMatrix.MakeZRotation(rng.uniform(0, 2 * np.pi))
            # turned about the plant base, then moved along / behind the row
            X = RigidTransform(at(along, back, 0.0)) @ RigidTransform(turn) @ \
                RigidTransform(-base)
            for part, cls, tag in ((canopy[0], LEAF, "leaves"), (canopy[1], BRANCH, "stems")):
                _Visual(plant, f"gh_row_{k}_{tag}", X, _ObjMesh(part, f"gh_row_{k}_{tag}"),
                        Rgba(*c, 1.0), EncodeNeighbourLabel(cls))
