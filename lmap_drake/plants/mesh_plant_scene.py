"""Adds a plant from files (``plant_scene.kind: mesh_plant``, a
``MeshPlantModel``) to the station's MultibodyPlant: stems welded (their
meshes as visuals labelled ``EncodeLabel(BRANCH, b)``, cylinders along their
centre lines for collision), fruits welded (``EncodeLabel(FRUIT, i)``,
collision ``fruit_<i>_collision``), static leaves welded as visuals
(``EncodeLabel(LEAF, len(model.leaves) + s)``; textured where the file is),
and the FEM leaves (``leaf_<j>``, ``EncodeLabel(LEAF, j)``) as
``greenhouse_scene.AddGreenhousePlant`` adds them. Optional greenhouse
dressing around the plant."""
from __future__ import annotations

import dataclasses as dc
import io

import numpy as np
from pydrake.common import MemoryFile
from pydrake.geometry import (CollisionFilterDeclaration, Cylinder, GeometryInstance,
                              GeometrySet, IllustrationProperties, InMemoryMesh, Mesh,
                              PerceptionProperties, RenderLabel, Rgba)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant

from lmap_drake.labels import BRANCH, FRUIT, LEAF, EncodeLabel
from lmap_drake.plants.config import PlantSceneConfig
from lmap_drake.plants.greenhouse_scene import AddGreenhouseDressing
from lmap_drake.plants.mesh_plant import PartVisual
from lmap_drake.plants.scene import (AddFemLeaf, AddPlantBody, LeafBodyName,
                                     RegisterLabeledGeometry,
                                     _CylinderBetween, _ObjMesh)


def _TexturedObj(visual: PartVisual, name: str) -> Mesh:
    """An in-memory OBJ + MTL + PNG of a textured visual."""
    V, F, uv = np.asarray(visual.mesh.vertices), np.asarray(visual.mesh.faces), visual.uv
    lines = [f"mtllib {name}.mtl", "usemtl leaf"]
    lines += [f"v {x:.7g} {y:.7g} {z:.7g}" for x, y, z in V]
    lines += [f"vt {u:.6g} {v:.6g}" for u, v in uv]
    lines += [f"vn {x:.5g} {y:.5g} {z:.5g}" for x, y, z in visual.mesh.vertex_normals]
    lines += [f"f {a}/{a}/{a} {b}/{b}/{b} {c}/{c}/{c}" for a, b, c in F + 1]
    png = io.BytesIO()
    visual.image.save(png, format="PNG")
    mtl = f"newmtl leaf\nKa 0 0 0\nKd 1 1 1\nKs 0 0 0\nmap_Kd {name}.png\n"
    data = InMemoryMesh()
    data.mesh_file = MemoryFile("\n".join(lines) + "\n", ".obj", name + ".obj")
    data.supporting_files = {f"{name}.mtl": MemoryFile(mtl, ".mtl", name + ".mtl"),
                             f"{name}.png": MemoryFile(png.getvalue(), ".png", name + ".png")}
    return Mesh(data)


def _AddVisual(plant, body, visual: PartVisual, name: str, label: int) -> None:
    """A welded visual: textured (the file's texture) or in its colour."""
    if visual.image is None or visual.uv is None:
        RegisterLabeledGeometry(plant, body, RigidTransform(), _ObjMesh(visual.mesh, name), name,
                                Rgba(*visual.color), label, collision=False)
        return
    gi = GeometryInstance(RigidTransform(), _TexturedObj(visual, name), name)
    gi.set_illustration_properties(IllustrationProperties())
    per = PerceptionProperties()
    per.AddProperty("label", "id", RenderLabel(label))
    gi.set_perception_properties(per)
    plant.RegisterVisualGeometry(body, gi)


def AddMeshPlant(plant: MultibodyPlant, scene_graph, model, cfg: PlantSceneConfig,
                 with_leaves: bool = True) -> dict:
    """Adds a ``MeshPlantModel``; handles as ``scene.AddMultiPlant``
    (``branch_geometry_ids`` per stem, ``fruit_geometry_ids``,
    ``leaf_body_ids`` / ``leaf_geometry_ids`` of the FEM leaves). FEM leaves
    collide with the fruits and the robot, not with the stems or static
    leaves (their petioles touch the stems) nor with each other unless
    ``multi.leaf_leaf_contact``."""
    world, instance, body = AddPlantBody(plant, cfg)
    branch_gids = []
    for b, (br, vis) in enumerate(zip(model.branches, model.stem_visuals)):
        _AddVisual(plant, body, vis, f"stem_{b}", EncodeLabel(BRANCH, b))
        gids = []
        for k in range(len(br.points_W) - 1):
            X, length = _CylinderBetween(br.points_W[k], br.points_W[k + 1])
            if length > 1e-6:
                gids.append(plant.RegisterCollisionGeometry(
                    body, X, Cylinder(br.radius, length), f"stem_{b}_{k}_collision",
                    CoulombFriction(0.8, 0.8)))
        branch_gids.append(gids)
    fruit_ids = []
    for i, (f, vis) in enumerate(zip(model.fruits, model.fruit_visuals)):
        _AddVisual(plant, world, vis, f"fruit_{i}", EncodeLabel(FRUIT, i))
        fruit_ids.append(plant.RegisterCollisionGeometry(
            world, RigidTransform(), _ObjMesh(f.mesh_W, f"fruit_{i}_collision"),
            f"fruit_{i}_collision", CoulombFriction(0.5, 0.5)))
    handles = {"branch_body": body, "branch_geometry_ids": branch_gids,
               "fruit_geometry_ids": fruit_ids, "leaf_body_ids": [], "leaf_geometry_ids": []}
    mp = cfg.mesh_plant
    if mp.dressing:
        AddGreenhouseDressing(plant, mp.X_W_plant.GetRigidTransform().translation(),
                              np.asarray(model.p_WC, float), None)
    if not with_leaves:
        return handles
    K = len(model.leaves)
    static_gids = []
    for s, lf in enumerate(model.static_leaves):
        _AddVisual(plant, world, lf.visual, f"static_leaf_{s}", EncodeLabel(LEAF, K + s))
        if mp.static_leaf_collision:
            static_gids.append(plant.RegisterCollisionGeometry(
                world, RigidTransform(), _ObjMesh(lf.surface_W, f"static_leaf_{s}_collision"),
                f"static_leaf_{s}_collision", CoulombFriction(0.8, 0.8)))
    cfm = scene_graph.collision_filter_manager()
    rigid = [g for gids in branch_gids for g in gids] + static_gids
    for j, leaf in enumerate(model.leaves):
        bid, gid = AddFemLeaf(plant, LeafBodyName(True, j), leaf.rest_W, leaf.tets, leaf.fixed,
                              dc.replace(cfg.leaf, color=Rgba(*model.leaf_colors[j][0])),
                              EncodeLabel(LEAF, j))
        handles["leaf_body_ids"].append(bid)
        handles["leaf_geometry_ids"].append(gid)
        if rigid:
            cfm.Apply(CollisionFilterDeclaration().ExcludeBetween(GeometrySet(gid),
                                                                  GeometrySet(rigid)))
    if handles["leaf_geometry_ids"] and not cfg.multi.leaf_leaf_contact:
        cfm.Apply(CollisionFilterDeclaration().ExcludeWithin(
            GeometrySet(handles["leaf_geometry_ids"])))
    return handles
