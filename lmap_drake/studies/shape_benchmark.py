"""Synthetic shape-completion benchmark (world frame W, metres): a pepper of
the project's family (``SamplePepperShape``) posed in front of the default
camera (``station.config.DefaultCameraConfig``, 640x480 L515-like intrinsics),
a branch rising from its peduncle, and a thin leaf-like plate between camera
and fruit hiding a chosen fraction of it. Observed points come from ray
casting (open3d ``RaycastingScene``) with 0.5 mm depth noise; they are
labelled exactly (no segmentation error). ``occluded=False`` removes the
leaf ("without occlusion" in paper Table I).

This stands in for the 12-scenario plant suite when ``diagrams/suite.yaml``
does not exist yet.
"""
from __future__ import annotations

import dataclasses as dc

import numpy as np
import open3d as o3d
from scipy.spatial.transform import Rotation

from lmap_drake.plants.pepper import VARIANTS, MakePepper, SamplePepperShape
from lmap_drake.station.config import DefaultCameraConfig, L515_640x480
from lmap_drake.types import SemanticScene


@dc.dataclass
class ShapeCase:
    """One benchmark scene and its ground truth (W, m)."""
    name: str
    semantic: SemanticScene
    gt_vertices_W: np.ndarray
    gt_faces: np.ndarray
    gt_center_W: np.ndarray
    gt_axis_W: np.ndarray
    visible_fraction: float = 1.0
    source: str = "synthetic"


def DefaultCamera() -> tuple[np.ndarray, dict]:
    """X_WC (4x4; camera x right, y down, z forward) and intrinsics of the
    default scenario's camera0."""
    cfg = DefaultCameraConfig()
    X = np.asarray(cfg.X_PB.GetDeterministicValue().GetAsMatrix4(), float)
    return X, dict(L515_640x480)


def _cylinder(p0, d, length, radius, n=24):
    import trimesh
    m = trimesh.creation.cylinder(radius=radius, height=length, sections=n)
    z = np.array([0, 0, 1.0])
    rot, _ = Rotation.align_vectors([d], [z])
    m.apply_transform(_h(rot.as_matrix(), p0 + 0.5 * length * d))
    return m


def _h(R, t):
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = R, t
    return X


def _scene(meshes):
    scene = o3d.t.geometry.RaycastingScene()
    ids = []
    for m in meshes:
        ids.append(scene.add_triangles(o3d.t.geometry.TriangleMesh(
            o3d.core.Tensor(np.asarray(m.vertices, np.float32)),
            o3d.core.Tensor(np.asarray(m.faces, np.int32)))))
    return scene, ids


def _rays(X_WC, K, roi=None, stride: int = 1):
    w, h = K["width"], K["height"]
    u, v = np.meshgrid(np.arange(0, w, stride) + 0.5, np.arange(0, h, stride) + 0.5)
    u, v = u.ravel(), v.ravel()
    if roi is not None:
        m = (u >= roi[0]) & (u <= roi[2]) & (v >= roi[1]) & (v <= roi[3])
        u, v = u[m], v[m]
    d_C = np.stack([(u - K["cx"]) / K["fx"], (v - K["cy"]) / K["fy"], np.ones_like(u)], 1)
    d_W = d_C @ X_WC[:3, :3].T
    d_W /= np.linalg.norm(d_W, axis=1, keepdims=True)
    o = np.broadcast_to(X_WC[:3, 3], d_W.shape)
    return o, d_W


def _cast(meshes, X_WC, K, roi=None):
    scene, ids = _scene(meshes)
    o, d = _rays(X_WC, K, roi)
    ans = scene.cast_rays(o3d.core.Tensor(np.c_[o, d].astype(np.float32)))
    t = ans["t_hit"].numpy().astype(float)
    gid = ans["geometry_ids"].numpy().astype(np.int64)
    hit = np.isfinite(t)
    return o[hit], d[hit], t[hit], gid[hit], ids


def _background(meshes, X_WC, K, roi=None, stride: int = 2, no_return_range: float = 2.0):
    """Ray ends of every ``stride``-th pixel that hits no mesh, at
    ``no_return_range`` m (as perception's ``BackgroundRayEnds`` for +inf
    depth in simulation)."""
    scene, _ = _scene(meshes)
    o, d = _rays(X_WC, K, roi, stride)
    t = scene.cast_rays(o3d.core.Tensor(np.c_[o, d].astype(np.float32)))["t_hit"].numpy()
    miss = ~np.isfinite(t)
    return o[miss] + d[miss] * no_return_range


def MakeSyntheticCase(seed: int, occluded: bool = True,
                      occlusion_range=(0.35, 0.75), noise: float = 0.0005) -> ShapeCase:
    """Scene ``seed`` of the synthetic benchmark (see the module docstring)."""
    rng = np.random.default_rng(1000 + seed)
    X_WC, K = DefaultCamera()
    cam = X_WC[:3, 3]
    shape = SamplePepperShape(rng, VARIANTS[seed % 3])
    pep = MakePepper(shape, subdivisions=4)
    # Like the plant world (lmap_drake.plants.generator): a near-vertical
    # branch, the pepper hanging beside it (as seen from the camera), a
    # peduncle stalk from the fruit top up to the branch (labelled branch).
    p0 = np.array([0.5, 0.0, 0.33]) + rng.uniform(-0.02, 0.02, 3)
    to_cam = cam - p0
    d_fwd = np.array([to_cam[0], to_cam[1], 0.0]) / np.linalg.norm(to_cam[:2])
    e_lat = np.cross([0, 0, 1.0], d_fwd) * (1 if rng.uniform() < 0.5 else -1)
    az, el = rng.uniform(0, 2 * np.pi), np.radians(rng.uniform(0, 8))
    d_b = np.array([np.sin(el) * np.cos(az), np.sin(el) * np.sin(az), np.cos(el)])
    r_b = rng.uniform(0.004, 0.007)
    branch = _cylinder(p0 - 0.15 * d_b, d_b, 0.35, r_b)
    tilt_axis = rng.normal(size=2)
    tilt_axis = np.r_[tilt_axis / np.linalg.norm(tilt_axis), 0.0]
    R_WO = (Rotation.from_rotvec(tilt_axis * np.radians(rng.uniform(0, 15)))
            * Rotation.from_euler("z", rng.uniform(0, 2 * np.pi))).as_matrix()
    r_xy = 0.5 * max(shape.size[0], shape.size[1])
    p_WO = p0 + e_lat * (r_b + r_xy + 0.004)
    fruit = pep.mesh.copy()
    fruit.apply_transform(_h(R_WO, p_WO))
    top = R_WO @ pep.p_O_peduncle + p_WO
    tip = top + R_WO[:, 2] * 0.015
    s_end = (tip[2] + 0.005 - p0[2]) / d_b[2]
    stalk_end = p0 + s_end * d_b + e_lat * 0.5 * r_b
    stalk_dir = (stalk_end - top) / np.linalg.norm(stalk_end - top)
    stalk = _cylinder(top - 0.002 * stalk_dir, stalk_dir,
                      np.linalg.norm(stalk_end - top) + 0.002, 0.004, 12)
    import trimesh
    branch = trimesh.util.concatenate([branch, stalk])
    meshes = [fruit, branch]
    visible = 1.0
    # Region of interest: the fruit's projection plus a margin (pixels).
    pc = (np.asarray(fruit.vertices) - X_WC[:3, 3]) @ X_WC[:3, :3]
    uu = K["fx"] * pc[:, 0] / pc[:, 2] + K["cx"]
    vv = K["fy"] * pc[:, 1] / pc[:, 2] + K["cy"]
    roi = (uu.min() - 160, vv.min() - 200, uu.max() + 160, vv.max() + 60)
    # Visible fraction without the leaf, per pixel of the fruit.
    o, d, t, gid, ids = _cast(meshes, X_WC, K, roi)
    n_fruit_free = int((gid == ids[0]).sum())
    if occluded:
        view = p_WO - cam
        view /= np.linalg.norm(view)
        right = np.cross(view, [0, 0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, view)
        target = rng.uniform(*occlusion_range)
        best = None
        import trimesh
        for trial in range(40):
            size = (rng.uniform(0.08, 0.12), 0.002, rng.uniform(0.06, 0.09))
            leaf = trimesh.creation.box(extents=size)
            R_leaf = (Rotation.from_rotvec(right * np.radians(rng.uniform(-20, 20)))
                      * Rotation.from_rotvec(view * np.radians(rng.uniform(-30, 30)))).as_matrix()
            # Box y (thin) along the view direction.
            base = np.c_[right, view, up]
            off = rng.uniform(-0.06, 0.06, 2)
            c_leaf = p_WO - view * rng.uniform(0.05, 0.07) + off[0] * right + off[1] * up
            leaf_m = leaf.copy()
            leaf_m.apply_transform(_h(R_leaf @ base, c_leaf))
            _, _, _, g2, ids2 = _cast([fruit, branch, leaf_m], X_WC, K, roi)
            frac = (g2 == ids2[0]).sum() / max(n_fruit_free, 1)
            occl = 1 - frac
            if best is None or abs(occl - target) < abs(best[0] - target):
                best = (occl, leaf_m, frac)
            if abs(occl - target) < 0.05:
                break
        meshes.append(best[1])
        visible = float(best[2])
        o, d, t, gid, ids = _cast(meshes, X_WC, K, roi)
    return RenderCase(f"synthetic_{seed:02d}_{shape.variant}", fruit, [branch],
                      meshes[2] if occluded else None, X_WC, K,
                      gt_axis_W=R_WO[:, 2].copy(), noise=noise, rng=rng,
                      visible_fraction=visible, roi=roi)


def RenderCase(name, fruit, branch_meshes, leaf, X_WC, K, gt_axis_W, noise=0.0005,
               rng=None, visible_fraction=None, roi=None, source="synthetic",
               gt_center_W=None) -> ShapeCase:
    """Ray-casts fruit / branch / leaf meshes (W, m) from camera ``X_WC``
    into an exactly labelled SemanticScene (points within 0.3 m of the
    fruit; the rays that miss every mesh as background ray ends) and packs
    the ground truth."""
    from lmap_drake.shape.metrics import MeshCentroid
    rng = rng or np.random.default_rng(0)
    meshes = [fruit] + list(branch_meshes) + ([leaf] if leaf is not None else [])
    o, d, t, gid, ids = _cast(meshes, X_WC, K, roi)
    t = t + rng.normal(0, noise, len(t))
    pts = o + d * t[:, None]
    c = np.asarray(fruit.vertices).mean(0)
    near = np.linalg.norm(pts - c, axis=1) < 0.3
    lab = np.full(len(pts), -1)
    nb = len(branch_meshes)
    lab[gid == ids[0]] = 0
    for i in ids[1:1 + nb]:
        lab[gid == i] = 1
    if leaf is not None:
        lab[gid == ids[-1]] = 2
    fr, br, lf = (pts[(lab == k) & near] for k in range(3))
    if visible_fraction is None:
        visible_fraction = 1.0
        if leaf is not None:
            _, _, _, g0, i0 = _cast(meshes[:-1], X_WC, K, roi)
            visible_fraction = float(len(fr) / max((g0 == i0[0]).sum(), 1))
    sem = SemanticScene(
        background_points_W=_background(meshes, X_WC, K, roi),
        branch_points_W=br, leaf_points_W=lf, fruit_points_W=fr,
        branch_instance=np.zeros(len(br), np.int64), leaf_instance=np.zeros(len(lf), np.int64),
        fruit_instance=np.zeros(len(fr), np.int64), X_WC=np.asarray(X_WC, float))
    return ShapeCase(
        name=name, semantic=sem, gt_vertices_W=np.asarray(fruit.vertices),
        gt_faces=np.asarray(fruit.faces),
        gt_center_W=MeshCentroid(fruit.vertices, fruit.faces) if gt_center_W is None
        else np.asarray(gt_center_W, float),
        gt_axis_W=np.asarray(gt_axis_W, float), visible_fraction=visible_fraction,
        source=source)


SUITE_FILE = "diagrams/suite.yaml"


def SuiteScenarioNames(suite_file) -> list[str]:
    """The scenario names of a suite file, in order (its tags, e.g. a
    robot mount's ``!Rpy``, are not resolved)."""
    import yaml
    from pathlib import Path
    root = yaml.compose(Path(suite_file).read_text(), Loader=yaml.SafeLoader)
    if not isinstance(root, yaml.MappingNode):
        return []
    return [k.value for k, _ in root.value]


def MakeSuiteCase(suite_file, scenario_name: str, occluded: bool = True,
                  noise: float = 0.0005, scenario_text: str = "{}",
                  case_name: str | None = None) -> ShapeCase:
    """A case from the plant-world suite: ``GeneratePlant`` of the scenario's
    ``plant_scene`` (kind procedural; ``scenario_text``: YAML overrides, e.g.
    a ``plant_scene.fruit.mesh_file``), camera0's pose and intrinsics, the
    fruit, branch (+ peduncle stalk and a file fruit's peduncle mesh,
    labelled branch) and rest leaf ray-cast as above. ``occluded=False``
    removes the leaf."""
    import trimesh
    from lmap_drake.scenario import LoadScenario
    sc = LoadScenario(filename=suite_file, scenario_name=scenario_name,
                      scenario_text=scenario_text)
    cam = sc.cameras["camera0"]
    X_WC = np.asarray(cam.X_PB.GetDeterministicValue().GetAsMatrix4(), float)
    K = dict(width=cam.width, height=cam.height, fx=cam.focal_x(), fy=cam.focal_y(),
             cx=cam.principal_point()[0], cy=cam.principal_point()[1])
    from lmap_drake.plants.plant_station import GetPlantModel
    model = GetPlantModel(sc)        # cached: the two conditions share one plant
    branch = []
    bp = model.branch_points_W
    for i in range(len(bp) - 1):
        L = np.linalg.norm(bp[i + 1] - bp[i])
        branch.append(_cylinder(bp[i], (bp[i + 1] - bp[i]) / L, L, model.branch_radius))
    a, b = model.stalk_W
    L = np.linalg.norm(b - a)
    branch.append(_cylinder(a - 0.002 * (b - a) / L, (b - a) / L, L + 0.004,
                            sc.plant_scene.fruit.peduncle_radius, 12))
    if model.peduncle_mesh_W is not None:     # a file fruit's own stalk, labelled branch
        branch.append(model.peduncle_mesh_W)
    branch = [trimesh.util.concatenate(branch)]
    leaf = model.LeafSurface() if occluded else None
    return RenderCase(case_name or scenario_name, model.fruit_mesh_W, branch, leaf, X_WC, K,
                      gt_axis_W=model.peduncle_axis_W, noise=noise,
                      rng=np.random.default_rng(0), source="suite",
                      gt_center_W=model.fruit_center_W)
