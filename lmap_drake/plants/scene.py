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
from lmap_drake.plants.config import PlantSceneConfig
from lmap_drake.plants.pepper import MakePepperMesh, MeshToObjText


def RegisterLabeledGeometry(plant: MultibodyPlant, body: RigidBody, X_BG: RigidTransform,
                            shape: Shape, name: str, rgba: Rgba, label: int,
                            collision: bool = True, friction: float = 0.8):
    """Registers visual (illustration + perception with ``label``) and,
    optionally, collision geometry for ``body``; returns the collision
    geometry's id (None without)."""
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
        return plant.RegisterCollisionGeometry(body, X_BG, shape, name + "_collision",
                                               CoulombFriction(friction, friction))
    return None


def RegisterTexturedVisual(plant: MultibodyPlant, body: RigidBody, name: str, obj: str,
                           png: str, rgba: Rgba, label: int) -> None:
    """Visual geometry of ``body`` from the OBJ file ``obj`` (body frame,
    with texture coordinates) textured with the PNG ``png`` for the cameras
    (the white diffuse colour leaves the texture as it is: RenderEngineVtk
    multiplies them), ``rgba`` for illustration, labelled ``label``."""
    gi = GeometryInstance(RigidTransform(), Mesh(obj), name)
    ill = IllustrationProperties()
    ill.AddProperty("phong", "diffuse", rgba)
    per = PerceptionProperties()
    per.AddProperty("phong", "diffuse", Rgba(1.0, 1.0, 1.0, 1.0))
    per.AddProperty("phong", "diffuse_map", png)
    per.AddProperty("label", "id", RenderLabel(label))
    gi.set_illustration_properties(ill)
    gi.set_perception_properties(per)
    plant.RegisterVisualGeometry(body, gi)


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


# --- procedural plant with an FEM leaf -------------------------------------

def _CylinderBetween(p0, p1) -> tuple[RigidTransform, float]:
    """Pose (z along p0->p1, centred) and length of a cylinder between points."""
    from pydrake.math import RotationMatrix
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    d = p1 - p0
    length = float(np.linalg.norm(d))
    R = RotationMatrix.MakeFromOneVector(d / length, 2)
    return RigidTransform(R, (p0 + p1) / 2), length


def _ObjMesh(mesh, name: str) -> Mesh:
    data = InMemoryMesh()
    data.mesh_file = MemoryFile(MeshToObjText(mesh), ".obj", name + ".obj")
    return Mesh(data)


def AddPlantBody(plant: MultibodyPlant, cfg: PlantSceneConfig):
    """The plant's model instance ``plant_world`` and its rigid ``branch``
    body welded to the world (the stems', shoots' and fruits' geometry
    hangs from it). Returns (world body, instance, branch body)."""
    from pydrake.multibody.tree import SpatialInertia
    instance = plant.AddModelInstance("plant_world")
    body = plant.AddRigidBody("branch", instance, SpatialInertia.SolidCylinderWithMass(
        0.05, cfg.branch.radius, cfg.branch.length, [0, 0, 1]))
    plant.WeldFrames(plant.world_frame(), body.body_frame(), RigidTransform())
    return plant.world_body(), instance, body


def AddProceduralPlant(plant: MultibodyPlant, scene_graph, model, cfg: PlantSceneConfig,
                       with_leaf: bool = True) -> dict:
    """Adds ``model`` (a ``PlantModel``) to ``plant``: the branch as a rigid
    body welded to the world, the fruit welded to the world, and the leaf as
    a Drake FEM deformable body fixed to the branch at the petiole.

    ``with_leaf=False`` leaves the leaf out (for the unoccluded view).
    Returns handles: ``branch_body``, ``leaf_body_id``, ``leaf_geometry_id``,
    ``fruit_geometry_ids``."""
    from pydrake.geometry import CollisionFilterDeclaration, GeometrySet

    world, instance, branch_body = AddPlantBody(plant, cfg)
    pts = model.branch_points_W
    for i in range(len(pts) - 1):
        X, length = _CylinderBetween(pts[i], pts[i + 1])
        RegisterLabeledGeometry(plant, branch_body, X, Cylinder(model.branch_radius, length),
                                f"branch_{i}", cfg.branch.color, EncodeLabel(BRANCH, 0))
    X, length = _CylinderBetween(*model.stalk_W)
    RegisterLabeledGeometry(plant, branch_body, X,
                            Cylinder(cfg.fruit.peduncle_radius, length + 0.004), "peduncle",
                            cfg.branch.color, EncodeLabel(BRANCH, 0), collision=False)
    if getattr(model, "peduncle_mesh_W", None) is not None:   # a file fruit's own stalk
        RegisterLabeledGeometry(plant, branch_body, RigidTransform(),
                                _ObjMesh(model.peduncle_mesh_W, "peduncle_mesh"),
                                "peduncle_mesh", cfg.branch.color, EncodeLabel(BRANCH, 0),
                                collision=False)

    fruit = model.fruit_mesh_W
    fruit_ids = []
    stripes = model.fruit_stripe_faces
    parts = [(fruit.submesh([~stripes], append=True) if stripes.any() else fruit,
              cfg.fruit.color, "fruit")]
    if stripes.any():
        parts.append((fruit.submesh([stripes], append=True), cfg.fruit.stripe_color,
                      "fruit_stripes"))
    for mesh, color, name in parts:
        RegisterLabeledGeometry(plant, world, RigidTransform(), _ObjMesh(mesh, name), name,
                                color, EncodeLabel(FRUIT, 0), collision=False)
    # Collision geometry: the (closed) fruit mesh, for contact and queries.
    fruit_ids.append(plant.RegisterCollisionGeometry(
        world, RigidTransform(), _ObjMesh(fruit, "fruit_collision"), "fruit_collision",
        CoulombFriction(0.5, 0.5)))

    if not with_leaf:
        return {"branch_body": branch_body, "leaf_body_id": None, "leaf_geometry_id": None,
                "fruit_geometry_ids": fruit_ids}
    # (the branch is welded to the world, so the petiole is fixed to the world
    # body: Drake rejects constraints to a welded body's zero-dof clique)
    leaf_id, leaf_gid = AddFemLeaf(plant, LeafBodyName(False, 0), model.leaf_rest_W,
                                   model.leaf_tets, model.leaf_fixed, cfg.leaf,
                                   EncodeLabel(LEAF, 0))
    branch_gids = plant.GetCollisionGeometriesForBody(branch_body)
    scene_graph.collision_filter_manager().Apply(
        CollisionFilterDeclaration().ExcludeBetween(GeometrySet(leaf_gid),
                                                    GeometrySet(branch_gids)))
    return {"branch_body": branch_body, "leaf_body_id": leaf_id,
            "leaf_geometry_id": leaf_gid, "fruit_geometry_ids": fruit_ids}


# --- multi-fruit plant (kind: multi) ----------------------------------------

def LeafBodyName(multi: bool, j: int) -> str:
    """The FEM body name of leaf ``j``: ``leaf_<j>`` on a multi-fruit plant,
    ``leaf`` on a single one."""
    return f"leaf_{j}" if multi else "leaf"


def AddFemLeaf(plant, name: str, rest_W, tets, fixed, leaf_cfg, label: int,
               texture: tuple[str, str] | None = None):
    """Registers one FEM leaf (rest mesh ``rest_W`` (N, 3) world, m) fixed to
    the world at its ``fixed`` vertices (none: a free leaf); returns (body
    id, geometry id). ``texture`` (OBJ path, PNG path): the camera renders
    the OBJ (the leaf's surface with texture coordinates, embedded in and
    driven by the tetrahedra) with the PNG as its texture."""
    from pydrake.geometry import AddContactMaterial, Sphere
    from pydrake.multibody.fem import DeformableBodyConfig

    from lmap_drake.plants.leaf import TetMeshToVtk
    vtk = InMemoryMesh()
    vtk.mesh_file = MemoryFile(TetMeshToVtk(rest_W, tets), ".vtk", name + ".vtk")
    gi = GeometryInstance(RigidTransform(), Mesh(vtk), name)
    prox = ProximityProperties()
    AddContactMaterial(friction=CoulombFriction(0.8, 0.8), properties=prox)
    gi.set_proximity_properties(prox)
    ill = IllustrationProperties()
    ill.AddProperty("phong", "diffuse", leaf_cfg.color)
    gi.set_illustration_properties(ill)
    per = PerceptionProperties()
    per.AddProperty("phong", "diffuse", leaf_cfg.color if texture is None else Rgba(1, 1, 1, 1))
    if texture is not None:
        per.AddProperty("deformable", "embedded_mesh", texture[0])
        per.AddProperty("phong", "diffuse_map", texture[1])
    per.AddProperty("label", "id", RenderLabel(label))
    gi.set_perception_properties(per)
    body_cfg = DeformableBodyConfig()
    body_cfg.set_youngs_modulus(leaf_cfg.youngs_modulus)
    body_cfg.set_poissons_ratio(leaf_cfg.poissons_ratio)
    body_cfg.set_mass_density(leaf_cfg.mass_density)
    body_cfg.set_stiffness_damping_coefficient(leaf_cfg.stiffness_damping)
    body_cfg.set_mass_damping_coefficient(leaf_cfg.mass_damping)
    dm = plant.mutable_deformable_model()
    body_id = dm.RegisterDeformableBody(gi, body_cfg, 1.0)
    pts = rest_W[fixed]
    if len(pts):
        center = pts.mean(axis=0)
        radius = float(np.linalg.norm(pts - center, axis=1).max()) + 2e-4
        dm.AddFixedConstraint(body_id, plant.world_body(), RigidTransform(), Sphere(radius),
                              RigidTransform(center))
    return body_id, dm.GetGeometryId(body_id)


def AddMultiPlant(plant: MultibodyPlant, scene_graph, model, cfg: PlantSceneConfig,
                  with_leaves: bool = True, fruit_texture=None) -> dict:
    """Adds a ``MultiPlantModel`` to ``plant``: every stem/shoot as rigid
    cylinders welded to the world (label ``EncodeLabel(BRANCH, b)``, b the
    branch index: 0 the stem, i + 1 fruit i's shoot; a fruit's stalk carries
    its shoot's label), every fruit welded to the world (``EncodeLabel(FRUIT,
    i)``, collision geometry ``fruit_<i>_collision``) and every leaf as its
    own FEM body ``leaf_<j>`` (``EncodeLabel(LEAF, j)``) fixed at its
    petiole base. Leaves collide with the gripper, fruits, branches (not with
    the shoot their petiole sits on) and, unless
    ``cfg.multi.leaf_leaf_contact`` is false, with each other.

    ``fruit_texture(i, fruit, body_mesh)``, if given, returns (OBJ path, PNG
    path) for fruit ``i``'s body (its faces without the stripes) or None
    (flat colour).

    Returns handles: ``branch_geometry_ids`` (per branch), ``leaf_body_ids``,
    ``leaf_geometry_ids``, ``fruit_geometry_ids`` (per fruit)."""
    from pydrake.geometry import CollisionFilterDeclaration, GeometrySet

    world, instance, body = AddPlantBody(plant, cfg)
    branch_gids = []
    for b, br in enumerate(model.branches):
        gids = []
        pts = br.points_W
        for k in range(len(pts) - 1):
            X, length = _CylinderBetween(pts[k], pts[k + 1])
            # Shoots reach a little into the stem (no visible seam).
            length += br.radius if b > 0 else 0.0
            gids.append(RegisterLabeledGeometry(
                plant, body, X, Cylinder(br.radius, length), f"{br.name}_{k}", cfg.branch.color,
                EncodeLabel(BRANCH, b)))
        branch_gids.append(gids)
    fruit_ids = []
    for i, f in enumerate(model.fruits):
        X, length = _CylinderBetween(*f.stalk_W)
        RegisterLabeledGeometry(plant, body, X, Cylinder(f.stalk_radius, length + 0.004),
                                f"stalk_{i}", cfg.branch.color, EncodeLabel(BRANCH, f.shoot),
                                collision=False)
        if f.peduncle_mesh_W is not None:
            RegisterLabeledGeometry(plant, body, RigidTransform(),
                                    _ObjMesh(f.peduncle_mesh_W, f"peduncle_{i}"),
                                    f"peduncle_{i}", cfg.branch.color,
                                    EncodeLabel(BRANCH, f.shoot), collision=False)
        stripes = f.stripe_faces
        parts = [(f.mesh_W.submesh([~stripes], append=True) if stripes.any() else f.mesh_W,
                  f.color, f"fruit_{i}")]
        if stripes.any():
            parts.append((f.mesh_W.submesh([stripes], append=True), f.stripe_color,
                          f"fruit_{i}_stripes"))
        for mesh, color, name in parts:
            tex = (fruit_texture(i, f, mesh) if fruit_texture is not None and name == f"fruit_{i}"
                   else None)
            if tex is not None:
                RegisterTexturedVisual(plant, world, name, *tex, color, EncodeLabel(FRUIT, i))
                continue
            RegisterLabeledGeometry(plant, world, RigidTransform(), _ObjMesh(mesh, name), name,
                                    color, EncodeLabel(FRUIT, i), collision=False)
        fruit_ids.append(plant.RegisterCollisionGeometry(
            world, RigidTransform(), _ObjMesh(f.mesh_W, f"fruit_{i}_collision"),
            f"fruit_{i}_collision", CoulombFriction(0.5, 0.5)))
    handles = {"branch_body": body, "branch_geometry_ids": branch_gids,
               "fruit_geometry_ids": fruit_ids, "leaf_body_ids": [], "leaf_geometry_ids": []}
    if not with_leaves:
        return handles
    cfm = scene_graph.collision_filter_manager()
    for j, leaf in enumerate(model.leaves):
        bid, gid = AddFemLeaf(plant, LeafBodyName(True, j), leaf.rest_W, leaf.tets, leaf.fixed,
                              cfg.leaf, EncodeLabel(LEAF, j))
        handles["leaf_body_ids"].append(bid)
        handles["leaf_geometry_ids"].append(gid)
        # The petiole base lies inside its own shoot (or the stem).
        cfm.Apply(CollisionFilterDeclaration().ExcludeBetween(
            GeometrySet(gid), GeometrySet(branch_gids[leaf.shoot])))
    if not cfg.multi.leaf_leaf_contact:
        cfm.Apply(CollisionFilterDeclaration().ExcludeWithin(
            GeometrySet(handles["leaf_geometry_ids"])))
    return handles
