"""Adds the plant (branch, leaf, fruit) to the station's MultibodyPlant, with
render labels from ``lmap_drake.labels``."""
from __future__ import annotations

import numpy as np
from pydrake.common import MemoryFile
from pydrake.geometry import (Box, Cylinder, GeometryInstance, IllustrationProperties,
                              InMemoryMesh, Mesh, PerceptionProperties, ProximityProperties,
                              RenderLabel, Rgba, Shape)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import CoulombFriction, MultibodyPlant
from pydrake.multibody.tree import RigidBody

from lmap_drake.labels import BRANCH, FRUIT, LEAF, EncodeLabel
from lmap_drake.plants.pepper import MakePepperMesh, MeshToObjText
from lmap_drake.scenario import PlantSceneConfig


def RegisterLabeledGeometry(plant: MultibodyPlant, body: RigidBody, X_BG: RigidTransform,
                            shape: Shape, name: str, rgba: Rgba, label: int,
                            collision: bool = True, friction: float = 0.8) -> None:
    """Registers visual (illustration + perception with ``label``) and,
    optionally, collision geometry for ``body``."""
    gi = GeometryInstance(X_BG, shape, name)
    ill = IllustrationProperties()
    ill.AddProperty("phong", "diffuse", rgba)
    per = PerceptionProperties()
    per.AddProperty("phong", "diffuse", rgba)
    per.AddProperty("label", "id", RenderLabel(label))
    gi.set_illustration_properties(ill)
    gi.set_perception_properties(per)
    plant.RegisterVisualGeometry(body, gi)
    if collision:
        plant.RegisterCollisionGeometry(body, X_BG, shape, name + "_collision",
                                        CoulombFriction(friction, friction))


def AddPlaceholderPlant(plant: MultibodyPlant, cfg: PlantSceneConfig) -> dict:
    """Rigid stand-ins welded to the world: a branch cylinder, a leaf plate and
    a lobed pepper mesh. Returns ground truth (world frame, metres)."""
    world = plant.world_body()
    base = np.asarray(cfg.p_W_branch_base, float)
    RegisterLabeledGeometry(
        plant, world, RigidTransform(base + [0, 0, cfg.branch_length / 2]),
        Cylinder(cfg.branch_radius, cfg.branch_length), "branch", cfg.branch_color,
        EncodeLabel(BRANCH, 0))
    RegisterLabeledGeometry(
        plant, world, RigidTransform(np.asarray(cfg.leaf_center_W, float)),
        Box(*cfg.leaf_size), "leaf", cfg.leaf_color, EncodeLabel(LEAF, 0))
    mesh = MakePepperMesh(cfg.fruit_size, cfg.fruit_lobes)
    obj = InMemoryMesh()
    obj.mesh_file = MemoryFile(MeshToObjText(mesh), ".obj", "pepper.obj")
    center = np.asarray(cfg.fruit_center_W, float)
    RegisterLabeledGeometry(plant, world, RigidTransform(center), Mesh(obj), "fruit",
                            cfg.fruit_color, EncodeLabel(FRUIT, 0))
    return {"fruit_center_W": center, "fruit_volume": float(mesh.volume),
            "fruit_mesh_W": mesh.copy().apply_translation(center)}
