"""Procedural pepper plants: a (slightly curved) branch, a pepper hanging
beside it, and a leaf whose blade hangs in front of the pepper, swung
sideways until it hides a chosen fraction of the fruit from the camera.

Everything is a pure function of the config (deterministic); world frame W,
metres. The leaf is returned as a two-layer tetrahedral mesh in its rest
configuration (the FEM reference mesh).
"""
from __future__ import annotations

import dataclasses as dc
import json
from pathlib import Path

import numpy as np
import trimesh

from lmap_drake.plants.leaf import (BoundaryTriangles, ExtrudeToTets, LeafShape,
                                    OrientTets, TriangulateLeaf, HalfWidth)
from lmap_drake.errors import InputError
from lmap_drake.plants.pepper import MakePepper, PepperShapeOf

# A generated plant's occlusion (ray cast from camera0) may differ from the
# requested ``plant_scene.occlusion`` by at most OCCLUSION_TOLERANCE. When
# the leaf cannot hide as much as requested, the most it can hide is used if
# that is within OCCLUSION_CLAMP of the request (a documented clamp, recorded
# as ``occlusion_requested`` / ``occlusion_clamped`` in ground_truth.json and
# episode.json). Anything else is a PlantGenerationError.
OCCLUSION_TOLERANCE = 0.05
OCCLUSION_CLAMP = 0.2


class PlantGenerationError(InputError, ValueError):
    """The requested plant cannot be built as described (the message says
    which scenario key to change)."""


@dc.dataclass
class PlantModel:
    """A generated plant (world frame, metres). ``leaf_rest_W`` (N, 3) and
    ``leaf_tets`` (T, 4) are the FEM reference mesh; ``leaf_uv`` gives each
    vertex's leaf coordinates (u along the midrib, v lateral, m); vertices
    with ``leaf_fixed`` are attached to the branch (petiole base)."""
    branch_points_W: np.ndarray      # (K, 3) centre line, base to top
    branch_radius: float
    fruit_mesh_W: trimesh.Trimesh
    fruit_stripe_faces: np.ndarray   # bool per face (stripe colour)
    X_WO: np.ndarray                 # fruit canonical frame -> world, 4x4
    fruit_center_W: np.ndarray
    peduncle_axis_W: np.ndarray
    peduncle_tip_W: np.ndarray
    stalk_W: np.ndarray              # (2, 3) peduncle stalk: fruit top -> branch
    fruit_volume: float
    leaf_rest_W: np.ndarray
    leaf_tets: np.ndarray
    leaf_uv: np.ndarray
    leaf_fixed: np.ndarray           # bool per vertex
    leaf_attach_W: np.ndarray
    leaf_normal_W: np.ndarray        # blade normal, pointing to the camera
    leaf_midrib_W: np.ndarray        # unit blade midrib direction (base -> tip)
    leaf_swing_deg: float
    occlusion_predicted: float       # fraction of camera-visible fruit surface hidden
    occlusion_requested: float = float("nan")   # plant_scene.occlusion
    occlusion_clamped: bool = False  # the leaf could not hide as much as requested
    peduncle_mesh_W: trimesh.Trimesh | None = None   # a file fruit's stalk (labelled branch)
    fruit_file: str = ""             # plant_scene.fruit.mesh_file (resolved), "" = procedural
    fruit_mesh_repairs: list = dc.field(default_factory=list)

    @property
    def branch_axis_W(self) -> np.ndarray:
        d = self.branch_points_W[-1] - self.branch_points_W[0]
        return d / np.linalg.norm(d)

    def LeafSurface(self) -> trimesh.Trimesh:
        """Boundary triangles of the rest leaf (for ray casting and display)."""
        return trimesh.Trimesh(self.leaf_rest_W, BoundaryTriangles(self.leaf_tets),
                               process=False)

    def GroundTruthDict(self) -> dict:
        return {"fruit_center_W": self.fruit_center_W.tolist(),
                "peduncle_axis_W": self.peduncle_axis_W.tolist(),
                "fruit_volume_m3": self.fruit_volume,
                "X_WO": self.X_WO.tolist(),
                "branch_axis_W": self.branch_axis_W.tolist(),
                "branch_points_W": self.branch_points_W.tolist(),
                "branch_radius": self.branch_radius,
                "leaf_attach_W": self.leaf_attach_W.tolist(),
                "leaf_swing_deg": self.leaf_swing_deg,
                "occlusion_predicted": self.occlusion_predicted,
                "occlusion_requested": self.occlusion_requested,
                "occlusion_clamped": self.occlusion_clamped,
                "leaf_num_vertices": int(len(self.leaf_rest_W)),
                "leaf_num_tets": int(len(self.leaf_tets)),
                "fruit_source": self.fruit_file or "procedural",
                "fruit_mesh_repairs": list(self.fruit_mesh_repairs)}


def SaveGroundTruth(model: PlantModel, folder: str | Path) -> list[str]:
    """Writes ``ground_truth.json``, ``fruit_W.obj`` and ``leaf_rest_W.obj``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "ground_truth.json").write_text(json.dumps(model.GroundTruthDict(), indent=2))
    model.fruit_mesh_W.export(folder / "fruit_W.obj")
    model.LeafSurface().export(folder / "leaf_rest_W.obj")
    return ["ground_truth.json", "fruit_W.obj", "leaf_rest_W.obj"]


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _rot_about(axis, angle) -> np.ndarray:
    a = _unit(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def BranchCenterline(base, length: float, bend: float, lateral, n: int = 9) -> np.ndarray:
    """Centre line points from the base up; ``bend`` (m) bows the middle
    sideways along ``lateral``."""
    t = np.linspace(0, 1, n)
    return (np.asarray(base, float)[None] + np.outer(t * length, [0, 0, 1])
            + np.outer(bend * np.sin(np.pi * t), _unit(lateral)))


def BranchPointsAtHeights(points: np.ndarray, z) -> np.ndarray:
    """Points (N, 3) of the centre line ``points`` (rising in z) at heights
    ``z`` (N,), linearly interpolated (clamped at the ends)."""
    z = np.atleast_1d(np.asarray(z, float))
    return np.stack([np.interp(z, points[:, 2], points[:, i]) for i in range(3)], 1)


def _branch_point_at_height(points: np.ndarray, z: float) -> np.ndarray:
    return BranchPointsAtHeights(points, z)[0]


def OffsetBesideBranch(V_W: np.ndarray, branch: np.ndarray, e_lat: np.ndarray,
                       d_fwd: np.ndarray, clearance: float) -> float:
    """Smallest shift x (m) along ``e_lat`` that puts the fruit vertices
    ``V_W + x e_lat`` on the ``e_lat`` side of the (near-vertical) branch
    centre line ``branch`` with every vertex at least ``clearance`` (m)
    from it horizontally (bisection; exact for any fruit pose)."""
    V = np.asarray(V_W, float)

    def ok(x: float) -> bool:
        P = V + x * e_lat
        off = P - BranchPointsAtHeights(branch, P[:, 2])
        off[:, 2] = 0.0
        if np.min(np.linalg.norm(off, axis=1)) < clearance:
            return False
        strip = np.abs(off @ d_fwd) < clearance      # vertices level with the branch
        return not strip.any() or float(np.min(off[strip] @ e_lat)) > 0.0
    lo, hi = -0.3, 0.3
    if not ok(hi):
        raise PlantGenerationError("cannot place the fruit beside the branch within 0.3 m "
                                   "(check plant_scene.fruit.size and gap_to_branch)")
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if ok(mid) else (mid, hi)
    return hi


def _leaf_vertices(shape: LeafShape, nodes: np.ndarray, attach: np.ndarray, d_fwd: np.ndarray,
                   midrib: np.ndarray, reach: float, bend_radius: float) -> np.ndarray:
    """Maps leaf coordinates (u, v, layer) to world: the petiole leaves the
    branch along ``d_fwd``, bends by 90 deg (radius ``bend_radius``) into the
    blade direction ``midrib``, the blade plane sits ``reach`` in front."""
    lat = _unit(np.cross(midrib, d_fwd))
    s = nodes[:, 0] + shape.petiole_length          # arc length from the branch
    s1 = max(reach - bend_radius, 0.0)
    s2 = s1 + 0.5 * np.pi * bend_radius
    phi = np.clip((s - s1) / bend_radius, 0.0, 0.5 * np.pi)
    along = np.where(s < s1, s, np.where(s < s2, s1 + bend_radius * np.sin(phi),
                                         s1 + bend_radius))
    down = np.where(s < s1, 0.0, np.where(s < s2, bend_radius * (1 - np.cos(phi)),
                                          bend_radius + (s - s2)))
    tangent = np.cos(phi)[:, None] * d_fwd + np.sin(phi)[:, None] * midrib
    normal = np.cross(tangent, lat)                 # in-plane normal of the surface
    w = (nodes[:, 2] - 1.0) * 0.5 * shape.thickness
    return (attach[None] + along[:, None] * d_fwd + down[:, None] * midrib
            + nodes[:, 1:2] * lat + w[:, None] * normal)


# Rays that vote inside/outside in open3d's signed distance: one ray that
# grazes an edge or a vertex flips the sign (a leaf vertex 10 cm from any
# fruit once measured 9.8 cm "inside" it); a majority of three does not.
SIGN_RAYS = 3


def MeshSignedDistance(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Signed distance (m, negative inside) from a watertight mesh, batched
    with open3d's RaycastingScene."""
    import open3d as o3d
    sc = o3d.t.geometry.RaycastingScene()
    sc.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                     o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)))
    q = o3d.core.Tensor(np.asarray(points, np.float32).reshape(-1, 3))
    return sc.compute_signed_distance(q, nsamples=SIGN_RAYS).numpy().astype(float)


def _ray_occlusion(fruit: trimesh.Trimesh, leaf: trimesh.Trimesh, others: list,
                   p_WC: np.ndarray, samples: np.ndarray) -> float:
    """Fraction of fruit surface samples visible from the camera without the
    leaf that the leaf hides (open3d ray casting)."""
    import open3d as o3d

    def scene_of(meshes):
        sc = o3d.t.geometry.RaycastingScene()
        ids = []
        for m in meshes:
            ids.append(sc.add_triangles(
                o3d.core.Tensor(np.asarray(m.vertices, np.float32)),
                o3d.core.Tensor(np.asarray(m.faces, np.uint32))))
        return sc, ids
    d = samples - p_WC[None]
    dist = np.linalg.norm(d, axis=1)
    rays = o3d.core.Tensor(np.c_[np.repeat(p_WC[None], len(d), 0), d / dist[:, None]]
                           .astype(np.float32))
    sc0, ids0 = scene_of([fruit] + others)
    hit0 = sc0.cast_rays(rays)
    visible = (hit0["geometry_ids"].numpy() == ids0[0]) & \
        (np.abs(hit0["t_hit"].numpy() - dist) < 2e-3)
    if not visible.any():
        return 0.0
    sc1, ids1 = scene_of([leaf])
    t_leaf = sc1.cast_rays(rays)["t_hit"].numpy()
    hidden = visible & (t_leaf < dist - 1e-3)
    return float(hidden.sum() / visible.sum())


def GeneratePlant(cfg, p_WC: np.ndarray) -> PlantModel:
    """Builds the plant described by ``cfg`` (a ``PlantSceneConfig`` with
    ``kind: procedural``; the fruit is the procedural pepper or, with
    ``fruit.mesh_file``, the file's mesh placed the same way), tuning the leaf's sideways swing so that it hides
    ``cfg.occlusion`` of the fruit surface visible from the camera at
    ``p_WC``."""
    p_WC = np.asarray(p_WC, float)
    b, lf, fr = cfg.branch, cfg.leaf, cfg.fruit
    base = np.asarray(cfg.p_W_branch_base, float)
    to_cam = p_WC - base
    d_fwd = _unit([to_cam[0], to_cam[1], 0.0])      # horizontal, toward the camera
    e_lat = _unit(np.cross([0, 0, 1], d_fwd)) * (1 if cfg.fruit_side >= 0 else -1)
    branch = BranchCenterline(base, b.length, b.bend, -e_lat)

    # Fruit: hanging beside the branch, axis tilted, peduncle stalk to the branch.
    file_fruit = None
    if fr.mesh_file:
        from lmap_drake.plants.fruit_mesh import LoadFruitMeshOf
        file_fruit = LoadFruitMeshOf(fr)
        pepper = file_fruit.AsPepper()
    else:
        pepper = MakePepper(PepperShapeOf(fr))
    tilt_axis = _rot_about([0, 0, 1], np.deg2rad(fr.tilt_azimuth_deg)) @ d_fwd
    R_WO = _rot_about(tilt_axis, np.deg2rad(fr.tilt_deg)) @ _rot_about(
        [0, 0, 1], np.arctan2(d_fwd[1], d_fwd[0]))
    if fr.lean_deg != 0.0:   # top toward the branch (direction -e_lat)
        R_WO = _rot_about(np.cross([0, 0, 1.0], -e_lat), np.deg2rad(fr.lean_deg)) @ R_WO
    z_center = base[2] + fr.height_on_branch
    p_branch_f = _branch_point_at_height(branch, z_center)
    center = p_branch_f + e_lat * OffsetBesideBranch(
        pepper.mesh.vertices @ R_WO.T + p_branch_f, branch, e_lat, d_fwd,
        b.radius + fr.gap_to_branch)
    X_WO = np.eye(4)
    X_WO[:3, :3] = R_WO
    X_WO[:3, 3] = center
    fruit = pepper.mesh.copy().apply_transform(X_WO)
    axis = R_WO[:, 2]
    top = center + R_WO @ pepper.p_O_peduncle
    tip = top + axis * fr.peduncle_length
    peduncle_W = None
    if pepper.peduncle is not None:         # a curved peduncle: procedural or a file's
        peduncle_W = pepper.peduncle.copy().apply_transform(X_WO)
        tip = center + R_WO @ pepper.p_O_peduncle_tip
    top_W = float(branch[-1, 2])
    if tip[2] + 0.005 > top_W:
        raise PlantGenerationError(
            f"the fruit's peduncle ends {tip[2] + 0.005 - top_W:.3f} m above the branch top "
            f"(z {top_W:.3f} m): the fruit would hang off the branch; lower "
            f"plant_scene.fruit.height_on_branch ({fr.height_on_branch} m) or lengthen "
            f"plant_scene.branch.length ({b.length} m)")
    stalk_end = _branch_point_at_height(branch, tip[2] + 0.005) + e_lat * 0.5 * b.radius
    stalk_start = top if peduncle_W is None else tip
    phi = np.arctan2(*(pepper.mesh.vertices[pepper.mesh.faces].mean(1)[:, [1, 0]].T))
    stripes = (np.cos(fr.stripes * (phi - 0.3)) > 0.75) if fr.stripes > 0 else \
        np.zeros(len(fruit.faces), bool)

    # Leaf: petiole from the branch above the fruit, blade in front of it.
    elem = lf.element_size if lf.element_size > 0 else float(
        np.sqrt(13.8 * 0.75 * lf.length * lf.width / max(lf.target_tets, 50)))
    leaf_shape = LeafShape(length=lf.length, width=lf.width, shape=lf.shape,
                           petiole_length=lf.petiole_length, petiole_width=lf.petiole_width,
                           thickness=lf.thickness, element_size=elem)
    uv, faces = TriangulateLeaf(leaf_shape)
    nodes, tets = ExtrudeToTets(uv, faces, layers=2)
    fruit_front = float(np.max((fruit.vertices - base) @ d_fwd))
    reach = fruit_front + lf.clearance
    z_attach = float(fruit.vertices[:, 2].max()) + lf.attach_above_fruit
    if z_attach > top_W:
        raise PlantGenerationError(
            f"the leaf would attach {z_attach - top_W:.3f} m above the branch top: lower "
            f"plant_scene.fruit.height_on_branch ({fr.height_on_branch} m) or "
            f"plant_scene.leaf.attach_above_fruit, or lengthen plant_scene.branch.length")
    attach = _branch_point_at_height(branch, z_attach) + d_fwd * b.radius * 0.5
    samples = trimesh.sample.sample_surface_even(fruit, 1500, seed=0)[0]
    others = [trimesh.creation.cylinder(b.radius, b.length,
                                        transform=trimesh.transformations.translation_matrix(
                                            base + [0, 0, b.length / 2]))]
    if peduncle_W is not None:
        others.append(peduncle_W)

    def build(swing_deg: float, reach_: float):
        side = 1.0 if cfg.fruit_side >= 0 else -1.0
        m = _rot_about(d_fwd, side * np.deg2rad(swing_deg)) @ np.array([0, 0, -1.0])
        m = _unit(m - (m @ d_fwd) * d_fwd)
        V = _leaf_vertices(leaf_shape, nodes, attach, d_fwd, m, reach_, lf.bend_radius)
        return V, m

    def occlusion(swing_deg: float, reach_: float) -> float:
        V, _ = build(swing_deg, reach_)
        leaf = trimesh.Trimesh(V, BoundaryTriangles(OrientTets(V, tets)), process=False)
        return _ray_occlusion(fruit, leaf, others, p_WC, samples)

    # Swing toward the fruit side is positive; find the most occluding swing,
    # then move away from the fruit until the target occlusion is reached.
    swings = np.linspace(-20.0, 70.0, 19)
    occ = np.array([occlusion(s, reach) for s in swings])
    best = float(swings[int(np.argmax(occ))])
    target = float(cfg.occlusion)
    if target >= occ.max():
        swing = best
    else:
        lo, hi = best, 90.0  # occlusion falls from best toward 90 deg
        for _ in range(14):
            mid = 0.5 * (lo + hi)
            if occlusion(mid, reach) > target:
                lo = mid
            else:
                hi = mid
        swing = 0.5 * (lo + hi)
    V, midrib = build(swing, reach)
    tets = OrientTets(V, tets)
    # Keep the leaf clear of the fruit (push the blade forward if needed).
    for _ in range(6):
        d = MeshSignedDistance(fruit, V)  # negative inside
        if d.min() > lf.min_fruit_clearance:
            break
        reach += lf.min_fruit_clearance - min(0.0, d.min()) + 0.002
        V, midrib = build(swing, reach)
        tets = OrientTets(V, tets)
    occ_final = occlusion(swing, reach)
    at_most = target >= occ.max()        # the leaf cannot hide more than this
    miss = target - occ_final
    if at_most and miss > OCCLUSION_CLAMP:
        raise PlantGenerationError(
            f"plant_scene.occlusion {target:.2f}: this leaf hides at most {occ_final:.2f} of "
            f"the fruit from camera0 (more than {OCCLUSION_CLAMP} below the request); use a "
            f"larger leaf (plant_scene.leaf.length / width) or a lower occlusion")
    if not at_most and abs(miss) > OCCLUSION_TOLERANCE:
        raise PlantGenerationError(
            f"plant_scene.occlusion {target:.2f} cannot be reached: the generated leaf hides "
            f"{occ_final:.2f} of the fruit from camera0 (tolerance {OCCLUSION_TOLERANCE}); "
            f"the leaf swing search covers -20..90 deg, so very low occlusions are out of "
            f"reach: raise plant_scene.occlusion")
    clamped = at_most and miss > OCCLUSION_TOLERANCE
    lat = _unit(np.cross(midrib, d_fwd))
    normal = _unit(np.cross(midrib, lat))
    if normal @ d_fwd < 0:
        normal = -normal
    fixed = nodes[:, 0] <= -lf.petiole_length + 0.5 * elem + 1e-9
    return PlantModel(
        branch_points_W=branch, branch_radius=b.radius, fruit_mesh_W=fruit,
        fruit_stripe_faces=stripes, X_WO=X_WO, fruit_center_W=center,
        peduncle_axis_W=axis, peduncle_tip_W=tip, stalk_W=np.array([stalk_start, stalk_end]),
        fruit_volume=float(fruit.volume), leaf_rest_W=V, leaf_tets=tets,
        leaf_uv=nodes[:, :2], leaf_fixed=fixed, leaf_attach_W=attach, leaf_normal_W=normal,
        leaf_midrib_W=midrib, leaf_swing_deg=swing, occlusion_predicted=occ_final,
        occlusion_requested=target, occlusion_clamped=bool(clamped), peduncle_mesh_W=peduncle_W,
        fruit_file=file_fruit.file if file_fruit else "",
        fruit_mesh_repairs=list(file_fruit.repairs) if file_fruit else [])


def LeafPointAt(model: PlantModel, u: float, v: float) -> np.ndarray:
    """World point of the rest leaf's mid-surface nearest to leaf coords (u, v)."""
    d = np.linalg.norm(model.leaf_uv - [u, v], axis=1)
    n = len(model.leaf_uv) // 3
    idx = int(np.argmin(d[n:2 * n])) + n  # middle layer
    return model.leaf_rest_W[idx]


def BladeHalfWidth(model_cfg_leaf, u: float) -> float:
    """Half-width (m) of the configured blade at midrib coordinate ``u``."""
    s = LeafShape(length=model_cfg_leaf.length, width=model_cfg_leaf.width,
                  shape=model_cfg_leaf.shape)
    return float(HalfWidth(s, np.array([u]))[0])
