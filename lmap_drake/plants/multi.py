"""Procedural plants with several fruits and several leaves (``plant_scene.kind:
multi``): a main stem, one side shoot per fruit (the fruit hangs from the
shoot's end), leaves on the shoots (over their fruit) and on the stem above
the top fruit. Each leaf is its own two-layer tet mesh with its petiole base
fixed to its shoot or stem point.

Pure functions of the config (deterministic); world frame W, metres. The
leaves over a fruit are swung (one leaf: sideways; two: spread apart) until
the fruit's surface visible from camera0 is hidden by ``occlusion``
(counting every leaf of the plant; ray cast like ``generator._ray_occlusion``).
Every leaf keeps ``multi.leaf_gap`` from the other leaves, the fruits, the
stem and the other shoots at rest (pushed forward, toward the camera, when
too close).
"""
from __future__ import annotations

import dataclasses as dc
import json
from pathlib import Path

import numpy as np
import trimesh

from lmap_drake.plants.generator import (OCCLUSION_CLAMP, OCCLUSION_TOLERANCE, SIGN_RAYS,
                                         BranchCenterline, BranchPointsAtHeights,
                                         OffsetBesideBranch, PlantGenerationError,
                                         _leaf_vertices, _rot_about, _unit)
from lmap_drake.plants.leaf import (BoundaryTriangles, ExtrudeToTets, LeafShape, OrientTets,
                                    TriangulateLeaf)
from lmap_drake.plants.pepper import MakePepper, PepperShapeOf

MAX_FRUITS, MIN_FRUITS = 4, 2
MAX_LEAVES, MIN_LEAVES = 6, 2
OCCLUDER_MIN = 0.02        # a leaf hiding at least this fraction of a fruit is one of its occluders
FRUIT_GAP = 0.005          # m, fruit to fruit and fruit to other shoots


class MultiConfigError(PlantGenerationError):
    """A bad ``plant_scene.multi`` value; ``key`` is the scenario key path."""

    def __init__(self, key: str, detail: str):
        super().__init__(f"{key} {detail}")
        self.key, self.detail = key, detail


@dc.dataclass
class Branch:
    """A stem or side shoot: centre line (K, 3) base to tip and radius (m).
    ``parent``: index of the branch it grows from (-1 for the stem)."""
    name: str
    points_W: np.ndarray
    radius: float
    parent: int = -1


@dc.dataclass
class MultiFruit:
    """One fruit (world frame, m): its mesh, pose ``X_WO`` (canonical fruit
    frame O, +z the peduncle axis), the stalk from the fruit to its shoot,
    and ``shoot`` (index into ``MultiPlantModel.branches``)."""
    mesh_W: trimesh.Trimesh
    stripe_faces: np.ndarray
    X_WO: np.ndarray
    center_W: np.ndarray
    peduncle_axis_W: np.ndarray
    peduncle_tip_W: np.ndarray
    stalk_W: np.ndarray                  # (2, 3): fruit top (or curved stalk tip) -> shoot
    volume: float
    shoot: int
    color: object = None                 # Rgba
    stripe_color: object = None
    stalk_radius: float = 0.004
    peduncle_mesh_W: trimesh.Trimesh | None = None
    fruit_file: str = ""                 # fruit.mesh_file (resolved), "" = procedural
    fruit_mesh_repairs: list = dc.field(default_factory=list)
    occlusion_requested: float = float("nan")
    occlusion_predicted: float = 0.0     # hidden fraction of the camera-visible surface, all leaves
    occlusion_clamped: bool = False
    occluders: list = dc.field(default_factory=list)   # leaf indices hiding >= OCCLUDER_MIN
    # the most of it camera0 sees with one leaf taken away entirely (the
    # others in place; 1 - hidden fraction): what one leaf's move can reveal
    one_leaf_ceiling: float = 1.0


@dc.dataclass
class MultiLeaf:
    """One FEM leaf at rest (world frame, m): vertices (N, 3), tets (T, 4),
    leaf coordinates ``uv`` (N, 2), ``fixed`` petiole-base vertices,
    ``attach_W`` the petiole base, ``shoot`` the branch index it sits on,
    ``fruit`` the fruit it was placed over (-1: a free leaf)."""
    rest_W: np.ndarray
    tets: np.ndarray
    uv: np.ndarray
    fixed: np.ndarray
    attach_W: np.ndarray
    shoot: int
    fruit: int
    midrib_W: np.ndarray
    normal_W: np.ndarray
    swing_deg: float
    reach: float

    def Surface(self) -> trimesh.Trimesh:
        return trimesh.Trimesh(self.rest_W, BoundaryTriangles(self.tets), process=False)


@dc.dataclass
class MultiPlantModel:
    """A generated multi-fruit plant (world frame, metres)."""
    branches: list[Branch]
    fruits: list[MultiFruit]
    leaves: list[MultiLeaf]
    p_WC: np.ndarray                     # camera0 position used for the occlusions

    def LeafSurface(self, i: int) -> trimesh.Trimesh:
        return self.leaves[i].Surface()

    def GroundTruthDict(self) -> dict:
        return {
            "kind": "multi",
            "camera0_p_WC": self.p_WC.tolist(),
            "branches": [{"name": b.name, "points_W": b.points_W.tolist(), "radius": b.radius,
                          "parent": b.parent} for b in self.branches],
            "fruits": [{"index": i, "fruit_center_W": f.center_W.tolist(),
                        "peduncle_axis_W": f.peduncle_axis_W.tolist(),
                        "peduncle_tip_W": f.peduncle_tip_W.tolist(),
                        "fruit_volume_m3": f.volume, "X_WO": f.X_WO.tolist(),
                        "shoot": f.shoot, "stalk_W": f.stalk_W.tolist(),
                        "occlusion_requested": (None if np.isnan(f.occlusion_requested)
                                                else f.occlusion_requested),
                        "occlusion_predicted": f.occlusion_predicted,
                        "occlusion_clamped": f.occlusion_clamped,
                        "occluders": list(f.occluders),
                        "one_leaf_ceiling": f.one_leaf_ceiling,
                        "fruit_source": f.fruit_file or "procedural",
                        "fruit_mesh_repairs": list(f.fruit_mesh_repairs),
                        "own_leaves": [j for j, lf in enumerate(self.leaves) if lf.fruit == i]}
                       for i, f in enumerate(self.fruits)],
            "leaves": [{"index": j, "leaf_attach_W": lf.attach_W.tolist(), "shoot": lf.shoot,
                        "fruit": lf.fruit, "leaf_swing_deg": lf.swing_deg, "reach": lf.reach,
                        "leaf_num_vertices": int(len(lf.rest_W)),
                        "leaf_num_tets": int(len(lf.tets))}
                       for j, lf in enumerate(self.leaves)]}


def SaveMultiGroundTruth(model: MultiPlantModel, folder: str | Path) -> list[str]:
    """Writes ``ground_truth.json``, ``fruit_<i>_W.obj`` and ``leaf_<j>_rest_W.obj``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "ground_truth.json").write_text(json.dumps(model.GroundTruthDict(), indent=2))
    names = ["ground_truth.json"]
    for i, f in enumerate(model.fruits):
        f.mesh_W.export(folder / f"fruit_{i}_W.obj")
        names.append(f"fruit_{i}_W.obj")
    for j, lf in enumerate(model.leaves):
        lf.Surface().export(folder / f"leaf_{j}_rest_W.obj")
        names.append(f"leaf_{j}_rest_W.obj")
    return names


# --- validation -----------------------------------------------------------

def ValidateMultiConfig(ps) -> None:
    """Checks ``plant_scene.multi`` (``ps`` a ``PlantSceneConfig``) before
    anything is built; raises MultiConfigError naming the key."""
    m = ps.multi
    key = "plant_scene.multi"

    def need(cond, path, msg):
        if not cond:
            raise MultiConfigError(f"{key}.{path}", msg)

    def num(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)
    n = len(m.fruits)
    need(MIN_FRUITS <= n <= MAX_FRUITS, "fruits",
         f"needs {MIN_FRUITS} to {MAX_FRUITS} fruits, got {n}")
    need(isinstance(m.num_leaves, int) and MIN_LEAVES <= m.num_leaves <= MAX_LEAVES,
         "num_leaves", f"must be {MIN_LEAVES} to {MAX_LEAVES}, got {m.num_leaves}")
    need(num(m.shoot_radius) and 0 < m.shoot_radius <= 0.02, "shoot_radius",
         f"must be in (0, 0.02] m, got {m.shoot_radius}")
    need(num(m.leaf_gap) and 0 <= m.leaf_gap <= 0.02, "leaf_gap",
         f"must be in [0, 0.02] m, got {m.leaf_gap}")
    need(num(m.free_leaf_swing_deg) and 0 <= m.free_leaf_swing_deg <= 90,
         "free_leaf_swing_deg", f"must be in [0, 90], got {m.free_leaf_swing_deg}")
    for i, f in enumerate(m.fruits):
        p = f"fruits[{i}]"
        need(isinstance(f.num_leaves, int) and 0 <= f.num_leaves <= 2, f"{p}.num_leaves",
             f"must be 0, 1 or 2, got {f.num_leaves}")
        need(num(f.occlusion) and (0 < f.occlusion < 1 if f.num_leaves else
                                   0 <= f.occlusion < 1), f"{p}.occlusion",
             f"must be in (0, 1) for a fruit with leaves, got {f.occlusion}")
        need(num(f.height) and 0 < f.height < ps.branch.length, f"{p}.height",
             f"must be in (0, plant_scene.branch.length = {ps.branch.length}) m, got {f.height}")
        need(num(f.side) and f.side != 0, f"{p}.side", f"must be +1 or -1, got {f.side}")
        need(num(f.shoot_extra) and 0 <= f.shoot_extra <= 0.1, f"{p}.shoot_extra",
             f"must be in [0, 0.1] m, got {f.shoot_extra}")
        need(num(f.shoot_rise_deg) and 0 <= f.shoot_rise_deg <= 60, f"{p}.shoot_rise_deg",
             f"must be in [0, 60], got {f.shoot_rise_deg}")
        need(not f.fruit.peduncle_file or f.fruit.mesh_file, f"{p}.fruit.peduncle_file",
             f"needs {key}.{p}.fruit.mesh_file (the procedural pepper has its own stalk)")
        if f.fruit.mesh_file:
            FileFruit(f.fruit, f"{key}.{p}.fruit")      # checked before anything is built
        need(len(f.fruit.size) == 3 and all(num(x) and x > 0 for x in f.fruit.size),
             f"{p}.fruit.size", f"needs 3 values > 0, got {list(f.fruit.size)}")
        for name in ("tilt_deg", "tilt_azimuth_deg", "peduncle_length", "peduncle_radius"):
            v = getattr(f.fruit, name)
            need(num(v) and (v > 0 if name.startswith("ped") else True), f"{p}.fruit.{name}",
                 f"must be a finite number{' > 0' if name.startswith('ped') else ''}, got {v}")
        try:
            PepperShapeOf(f.fruit).validate()
        except ValueError as err:
            raise MultiConfigError(f"{key}.{p}.fruit", f"is not a valid pepper shape: {err}")
    own = sum(f.num_leaves for f in m.fruits)
    need(own <= m.num_leaves, "num_leaves",
         f"({m.num_leaves}) is less than the fruits' leaves (sum of fruits[*].num_leaves = {own})")


# --- geometry helpers -----------------------------------------------------

def SegmentDistance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (m) from points (N, 3) to the segment a-b."""
    ab = b - a
    t = np.clip((points - a) @ ab / max(ab @ ab, 1e-12), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * ab), axis=1)


def BranchClearance(points: np.ndarray, branch: Branch) -> np.ndarray:
    """Distance (m) from points to the branch's tube surface (negative inside)."""
    P = branch.points_W
    d = np.min([SegmentDistance(points, P[k], P[k + 1]) for k in range(len(P) - 1)], axis=0)
    return d - branch.radius


def BranchTube(branch: Branch, sections: int = 12) -> trimesh.Trimesh:
    P = branch.points_W
    return trimesh.util.concatenate([
        trimesh.creation.cylinder(branch.radius, segment=P[k:k + 2], sections=sections)
        for k in range(len(P) - 1)])


def _o3d_scene(meshes):
    import open3d as o3d
    sc = o3d.t.geometry.RaycastingScene()
    for m in meshes:
        sc.add_triangles(o3d.core.Tensor(np.asarray(m.vertices, np.float32)),
                         o3d.core.Tensor(np.asarray(m.faces, np.uint32)))
    return sc


def SurfaceDistance(meshes: list, points: np.ndarray) -> np.ndarray:
    """Signed distance (m, negative inside) of points to the closed meshes."""
    import open3d as o3d
    if not meshes:
        return np.full(len(points), np.inf)
    q = o3d.core.Tensor(np.asarray(points, np.float32))
    return _o3d_scene(meshes).compute_signed_distance(q, nsamples=SIGN_RAYS).numpy().astype(float)


def MeshesCross(a: trimesh.Trimesh, b: trimesh.Trimesh) -> bool:
    """True if an edge of one triangle mesh passes through a face of the other."""
    import open3d as o3d
    for m, other in ((a, b), (b, a)):
        e = m.edges_unique
        p0, p1 = m.vertices[e[:, 0]], m.vertices[e[:, 1]]
        d = p1 - p0
        length = np.linalg.norm(d, axis=1)
        rays = o3d.core.Tensor(np.c_[p0, d / length[:, None]].astype(np.float32))
        t = _o3d_scene([other]).cast_rays(rays)["t_hit"].numpy()
        if np.any(t < length):
            return True
    return False


def LeafLeafGap(a: trimesh.Trimesh, b: trimesh.Trimesh) -> float:
    """Smallest vertex-to-surface distance (m) between two closed leaf
    surfaces, both ways; negative if they interpenetrate."""
    d = min(SurfaceDistance([b], a.vertices).min(), SurfaceDistance([a], b.vertices).min())
    if d > 0 and MeshesCross(a, b):
        return -1e-3
    return float(d)


class _FruitView:
    """camera0's view of one fruit without leaves: surface samples that the
    camera sees past the stem, shoots and other fruits."""

    def __init__(self, fruit: trimesh.Trimesh, others: list, p_WC: np.ndarray, n: int = 1200):
        import open3d as o3d
        samples = trimesh.sample.sample_surface_even(fruit, n, seed=0)[0]
        d = samples - p_WC[None]
        self.dist = np.linalg.norm(d, axis=1)
        self.rays = o3d.core.Tensor(np.c_[np.repeat(p_WC[None], len(d), 0),
                                          d / self.dist[:, None]].astype(np.float32))
        hit = _o3d_scene([fruit] + others).cast_rays(self.rays)
        self.visible = (hit["geometry_ids"].numpy() == 0) & \
            (np.abs(hit["t_hit"].numpy() - self.dist) < 2e-3)

    def Hidden(self, leaves: list) -> np.ndarray:
        """Mask over samples: visible without leaves, hidden by ``leaves``."""
        if not leaves or not self.visible.any():
            return np.zeros(len(self.dist), bool)
        t = _o3d_scene(leaves).cast_rays(self.rays)["t_hit"].numpy()
        return self.visible & (t < self.dist - 1e-3)

    def Occlusion(self, leaves: list) -> float:
        n = self.visible.sum()
        return float(self.Hidden(leaves).sum() / n) if n else 0.0


# --- the generator ---------------------------------------------------------

def FileFruit(fruit_cfg, key: str):
    """``LoadFruitMeshOf`` a fruit config with ``mesh_file`` set, its errors
    naming ``key`` (e.g. ``plant_scene.multi.fruits[1].fruit``) instead of
    ``plant_scene.fruit``."""
    from lmap_drake.plants.fruit_mesh import FruitMeshError, LoadFruitMeshOf
    try:
        return LoadFruitMeshOf(fruit_cfg)
    except FruitMeshError as err:
        raise MultiConfigError(err.key.replace("plant_scene.fruit", key, 1),
                               err.detail.replace("plant_scene.fruit.", key + ".")) from None


def _PlaceFruit(fc, i: int, stem: np.ndarray, base, d_fwd, e_lat, stem_radius, shoot_radius):
    """Fruit ``i`` of config ``fc`` (a MultiFruitConfig) beside the stem and
    its shoot (points from the stem to just beyond the peduncle); a
    ``fruit.mesh_file`` pepper is placed like the procedural one (its
    canonical frame: origin at the volume centroid, +z the peduncle axis)."""
    fr = fc.fruit
    file_fruit = None
    if fr.mesh_file:
        file_fruit = FileFruit(fr, f"plant_scene.multi.fruits[{i}].fruit")
        pepper = file_fruit.AsPepper()
    else:
        pepper = MakePepper(PepperShapeOf(fr))
    side = 1.0 if fc.side > 0 else -1.0
    e_out = side * e_lat
    tilt_axis = _rot_about([0, 0, 1], np.deg2rad(fr.tilt_azimuth_deg)) @ d_fwd
    R_WO = _rot_about(tilt_axis, np.deg2rad(fr.tilt_deg)) @ _rot_about(
        [0, 0, 1], np.arctan2(d_fwd[1], d_fwd[0]))
    z_c = base[2] + fc.height
    p_stem = BranchPointsAtHeights(stem, [z_c])[0]
    V0 = pepper.mesh.vertices @ R_WO.T
    off = OffsetBesideBranch(V0 + p_stem, stem, e_out, d_fwd, stem_radius + 0.006)
    center = p_stem + e_out * off
    top = center + R_WO @ pepper.p_O_peduncle
    axis = R_WO[:, 2]
    peduncle_W = None
    if pepper.peduncle is not None:
        tip = center + R_WO @ pepper.p_O_peduncle_tip
        peduncle_W = pepper.peduncle.copy().apply_transform(_X(R_WO, center))
    else:
        tip = top + axis * fr.peduncle_length
    # The shoot leaves the stem below the peduncle tip, rising outward.
    end = tip + np.array([0, 0, shoot_radius * 0.5])
    lateral = end - BranchPointsAtHeights(stem, [end[2]])[0]
    lateral[2] = 0.0
    L = float(np.linalg.norm(lateral))
    rise = np.tan(np.deg2rad(fc.shoot_rise_deg))
    node = BranchPointsAtHeights(stem, [end[2] - L * rise])[0]
    u = _unit(end - node)
    far = end + u * fc.shoot_extra
    shoot = np.array([node, 0.5 * (node + end), end, far]) if fc.shoot_extra > 0 else \
        np.array([node, 0.5 * (node + end), end])
    if node[2] < base[2] + 0.01 or far[2] > stem[-1, 2] - 0.005:
        raise MultiConfigError(f"plant_scene.multi.fruits[{i}].height",
                               f"{fc.height} m puts fruit {i}'s shoot (z {node[2]:.3f}.."
                               f"{far[2]:.3f} m) off the stem (z {base[2]:.3f}..{stem[-1, 2]:.3f})")
    mesh = pepper.mesh.copy().apply_transform(_X(R_WO, center))
    phi = np.arctan2(*(pepper.mesh.vertices[pepper.mesh.faces].mean(1)[:, [1, 0]].T))
    stripes = (np.cos(fr.stripes * (phi - 0.3)) > 0.75) if fr.stripes > 0 else \
        np.zeros(len(mesh.faces), bool)
    stalk = np.array([top if peduncle_W is None else tip, end])
    return MultiFruit(mesh_W=mesh, stripe_faces=stripes, X_WO=_X(R_WO, center),
                      center_W=center, peduncle_axis_W=axis, peduncle_tip_W=tip, stalk_W=stalk,
                      volume=float(mesh.volume), shoot=i + 1, color=fr.color,
                      stripe_color=fr.stripe_color, stalk_radius=fr.peduncle_radius,
                      peduncle_mesh_W=peduncle_W,
                      fruit_file=file_fruit.file if file_fruit else "",
                      fruit_mesh_repairs=list(file_fruit.repairs) if file_fruit else [],
                      occlusion_requested=float(fc.occlusion) if fc.num_leaves else float("nan")
                      ), shoot


def _X(R, p) -> np.ndarray:
    X = np.eye(4)
    X[:3, :3], X[:3, 3] = R, p
    return X


class _LeafFactory:
    """Builds leaves of the configured shape at an attach point, swing and
    reach, pushed forward until clear of the obstacles."""

    def __init__(self, lf, d_fwd, gap, fruit_gap):
        elem = lf.element_size if lf.element_size > 0 else float(
            np.sqrt(13.8 * 0.75 * lf.length * lf.width / max(lf.target_tets, 50)))
        self.shape = LeafShape(length=lf.length, width=lf.width, shape=lf.shape,
                               petiole_length=lf.petiole_length, petiole_width=lf.petiole_width,
                               thickness=lf.thickness, element_size=elem)
        uv, faces = TriangulateLeaf(self.shape)
        self.nodes, self.tets = ExtrudeToTets(uv, faces, layers=2)
        self.fixed = self.nodes[:, 0] <= -lf.petiole_length + 0.5 * elem + 1e-9
        self.lf, self.d_fwd, self.gap, self.fruit_gap = lf, d_fwd, gap, fruit_gap

    def Build(self, attach, swing_deg, reach, side) -> tuple[np.ndarray, np.ndarray]:
        d = self.d_fwd
        m = _rot_about(d, side * np.deg2rad(swing_deg)) @ np.array([0, 0, -1.0])
        m = _unit(m - (m @ d) * d)
        V = _leaf_vertices(self.shape, self.nodes, attach, d, m, reach, self.lf.bend_radius)
        return V, m

    def Clearance(self, V, tets, fruits, branches, leaves, skip_branch) -> float:
        """Smallest margin (m) over the obstacles: distance minus the required gap."""
        surf = trimesh.Trimesh(V, BoundaryTriangles(tets), process=False)
        c = float(SurfaceDistance(fruits, V).min()) - self.fruit_gap if fruits else np.inf
        not_petiole = self.nodes[:, 0] > 0.0   # the petiole may pass near its own shoot only
        for k, b in enumerate(branches):
            pts = V if k != skip_branch else V[not_petiole]
            c = min(c, float(BranchClearance(pts, b).min()) - self.gap)
        for other in leaves:
            c = min(c, LeafLeafGap(surf, other) - self.gap)
        return c

    def Place(self, attach, swing_deg, reach, side, fruits, branches, leaves, skip_branch,
              tries: int = 14):
        """(V, tets, midrib, reach, ok): pushed forward along d_fwd until the
        clearance to every obstacle holds (``ok`` False if it never did)."""
        for _ in range(tries):
            V, m = self.Build(attach, swing_deg, reach, side)
            tets = OrientTets(V, self.tets)
            c = self.Clearance(V, tets, fruits, branches, leaves, skip_branch)
            if c >= 0:
                return V, tets, m, reach, True
            reach += min(max(-c, 0.0) + 0.002, 0.01) if c > -0.5e-3 - self.gap else 0.008
        return V, tets, m, reach, False


def _AttachPoint(shoot: np.ndarray, fraction: float, d_fwd, radius) -> np.ndarray:
    """Point at ``fraction`` of the shoot's stem-to-peduncle length (points
    0..2), on its camera side."""
    a, b = shoot[0], shoot[2]
    return a + fraction * (b - a) + d_fwd * radius * 0.5


def GenerateMultiPlant(cfg, p_WC) -> MultiPlantModel:
    """Builds the plant of ``cfg`` (a ``PlantSceneConfig`` with ``kind:
    multi``) seen by camera0 at ``p_WC`` (m, world). Raises
    PlantGenerationError (naming the key) if it cannot be built as asked."""
    ValidateMultiConfig(cfg)
    p_WC = np.asarray(p_WC, float)
    mc, lf = cfg.multi, cfg.leaf
    base = np.asarray(cfg.p_W_branch_base, float)
    to_cam = p_WC - base
    d_fwd = _unit([to_cam[0], to_cam[1], 0.0])
    e_lat = _unit(np.cross([0, 0, 1], d_fwd))
    stem_pts = BranchCenterline(base, cfg.branch.length, cfg.branch.bend, e_lat)
    branches = [Branch("stem", stem_pts, cfg.branch.radius, -1)]
    fruits: list[MultiFruit] = []
    for i, fc in enumerate(mc.fruits):
        fruit, shoot = _PlaceFruit(fc, i, stem_pts, base, d_fwd, e_lat, cfg.branch.radius,
                                   mc.shoot_radius)
        fruits.append(fruit)
        branches.append(Branch(f"shoot_{i}", shoot, mc.shoot_radius, 0))
    # Fruits clear of each other and of the other shoots.
    for i, f in enumerate(fruits):
        for j, g in enumerate(fruits):
            if j > i and SurfaceDistance([g.mesh_W], f.mesh_W.vertices).min() < FRUIT_GAP:
                raise MultiConfigError(
                    f"plant_scene.multi.fruits[{j}].height",
                    f"({mc.fruits[j].height} m): fruit {j} touches fruit {i} (height "
                    f"{mc.fruits[i].height} m, same side: {mc.fruits[i].side == mc.fruits[j].side});"
                    f" space the fruits further apart or put them on opposite sides")
        for k, b in enumerate(branches[1:]):
            if k != i and BranchClearance(f.mesh_W.vertices, b).min() < FRUIT_GAP:
                raise MultiConfigError(
                    f"plant_scene.multi.fruits[{i}].height",
                    f"({mc.fruits[i].height} m): fruit {i} touches the shoot of fruit {k}")
    fruit_meshes = [f.mesh_W for f in fruits]
    branch_meshes = [BranchTube(b) for b in branches] + [
        trimesh.creation.cylinder(f.stalk_radius, segment=f.stalk_W) for f in fruits] + [
        f.peduncle_mesh_W for f in fruits if f.peduncle_mesh_W is not None]
    views = [_FruitView(f.mesh_W, [m for k, m in enumerate(fruit_meshes) if k != i] +
                        branch_meshes, p_WC) for i, f in enumerate(fruits)]
    factory = _LeafFactory(lf, d_fwd, mc.leaf_gap, lf.min_fruit_clearance)
    leaves: list[MultiLeaf] = []

    def make_leaf(V, tets, m, reach, attach, shoot, fruit, swing):
        lat = _unit(np.cross(m, d_fwd))
        normal = _unit(np.cross(m, lat))
        if normal @ d_fwd < 0:
            normal = -normal
        return MultiLeaf(rest_W=V, tets=tets, uv=factory.nodes[:, :2].copy(),
                         fixed=factory.fixed.copy(), attach_W=attach, shoot=shoot, fruit=fruit,
                         midrib_W=m, normal_W=normal, swing_deg=float(swing), reach=float(reach))

    # Free leaves on the stem above the top fruit's shoot, alternating sides
    # (the first opposite the top fruit).
    n_free = mc.num_leaves - sum(f.num_leaves for f in mc.fruits)
    top = int(np.argmax([f.height for f in mc.fruits]))
    z_lo = max(b.points_W[:, 2].max() for b in branches[1:]) + 0.02
    z_hi = stem_pts[-1, 2] - 0.02
    if n_free and z_hi - z_lo < 0.0:
        raise MultiConfigError("plant_scene.multi.num_leaves",
                               f"({mc.num_leaves}): no room on the stem above the top shoot "
                               f"(z {z_lo:.3f} m) for the {n_free} leaves not over a fruit; "
                               f"lengthen plant_scene.branch.length or lower the fruits")
    side0 = -(1.0 if mc.fruits[top].side > 0 else -1.0)
    for k in range(n_free):
        z = z_lo + (z_hi - z_lo) * (k / max(n_free - 1, 1) if n_free > 1 else 0.5)
        attach = BranchPointsAtHeights(stem_pts, [z])[0] + d_fwd * cfg.branch.radius * 0.5
        side = side0 * (1 if k % 2 == 0 else -1)
        surfs = [x.Surface() for x in leaves]
        V, tets, m, reach, ok = factory.Place(attach, mc.free_leaf_swing_deg, 0.03 + 0.008 * k,
                                              side, fruit_meshes, branches, surfs, 0)
        if not ok:
            raise MultiConfigError("plant_scene.multi.num_leaves",
                                   f"({mc.num_leaves}): free leaf {k} cannot be placed clear of "
                                   f"the other leaves; use fewer leaves")
        leaves.append(make_leaf(V, tets, m, reach, attach, 0, -1, mc.free_leaf_swing_deg))

    # Leaves over the fruits, top fruit first; then a second pass re-tunes
    # each fruit with every other leaf in place.
    slots: dict[int, list[int]] = {}
    order = sorted(range(len(fruits)), key=lambda i: -mc.fruits[i].height)
    for i in order:
        fc = mc.fruits[i]
        slots[i] = []
        for k in range(fc.num_leaves):
            leaves.append(None)
            slots[i].append(len(leaves) - 1)
    placed = {j for j, x in enumerate(leaves) if x is not None}

    def tune(i: int) -> None:
        fc, f = mc.fruits[i], fruits[i]
        idx = slots[i]
        n = len(idx)
        side = 1.0 if fc.side > 0 else -1.0
        shoot = branches[f.shoot].points_W
        fracs = [0.7] if n == 1 else [0.4, 1.0]
        others = [leaves[j] for j in sorted(placed) if j not in idx]
        other_surfs = [x.Surface() for x in others]

        def build(t: float):
            out, surfs = [], list(other_surfs)
            for k in range(n):
                attach = _AttachPoint(shoot, fracs[k], d_fwd, mc.shoot_radius)
                front = float(np.max((f.mesh_W.vertices - attach) @ d_fwd))
                reach = front + lf.clearance + k * (lf.thickness + mc.leaf_gap + 0.004)
                swing = t if n == 1 else (-t if k == 0 else t)
                V, tets, m, reach, ok = factory.Place(attach, swing, reach, side, fruit_meshes,
                                                      branches, surfs, f.shoot)
                if not ok:
                    return None
                leaf = make_leaf(V, tets, m, reach, attach, f.shoot, i, swing)
                out.append(leaf)
                surfs.append(leaf.Surface())
            return out

        def occ(t: float):
            new = build(t)
            if new is None:
                return -1.0, None
            return views[i].Occlusion(other_surfs + [x.Surface() for x in new]), new
        grid = np.linspace(-30.0, 90.0, 13) if n == 1 else np.linspace(0.0, 90.0, 10)
        res = [occ(t) for t in grid]
        vals = np.array([r[0] for r in res])
        if vals.max() < 0:
            raise MultiConfigError(f"plant_scene.multi.fruits[{i}].num_leaves",
                                   f"({n}): the leaves over fruit {i} cannot be placed clear of "
                                   f"the other leaves and fruits; use fewer leaves or move the "
                                   f"fruit (height / side)")
        b = int(np.argmax(vals))
        target = float(fc.occlusion)
        if target >= vals[b]:      # the most these leaves hide (checked below)
            new = res[b][1]
        else:
            lo, hi = float(grid[b]), 90.0
            best = (abs(vals[b] - target), float(grid[b]), res[b][1], float(vals[b]))
            for _ in range(12):
                mid = 0.5 * (lo + hi)
                o_mid, new_mid = occ(mid)
                if o_mid >= 0 and abs(o_mid - target) < best[0]:
                    best = (abs(o_mid - target), mid, new_mid, o_mid)
                if o_mid > target:
                    lo = mid
                else:
                    hi = mid
            new = best[2]
        for j, leaf in zip(idx, new):
            leaves[j] = leaf
            placed.add(j)

    for _pass in range(2):
        for i in order:
            if slots[i]:
                tune(i)

    surfs = [x.Surface() for x in leaves]
    for i, (f, fc) in enumerate(zip(fruits, mc.fruits)):
        f.occlusion_predicted = views[i].Occlusion(surfs)
        f.occluders = [j for j, s in enumerate(surfs) if views[i].Occlusion([s]) >= OCCLUDER_MIN]
        f.one_leaf_ceiling = max(
            [1.0 - views[i].Occlusion([x for k, x in enumerate(surfs) if k != j])
             for j in f.occluders] or [1.0 - f.occlusion_predicted])
        if not fc.num_leaves:
            continue
        target = float(fc.occlusion)
        miss = target - f.occlusion_predicted
        # The most the leaves can hide: the best grid value (tune clamps there).
        if miss > OCCLUSION_TOLERANCE:
            if miss > OCCLUSION_CLAMP:
                raise MultiConfigError(
                    f"plant_scene.multi.fruits[{i}].occlusion",
                    f"{target:.2f}: the leaves hide at most {f.occlusion_predicted:.2f} of fruit "
                    f"{i} from camera0 (more than {OCCLUSION_CLAMP} below the request); use a "
                    f"larger leaf, two leaves (num_leaves: 2) or a lower occlusion")
            f.occlusion_clamped = True
        elif miss < -OCCLUSION_TOLERANCE:
            raise MultiConfigError(
                f"plant_scene.multi.fruits[{i}].occlusion",
                f"{target:.2f} cannot be reached: the leaves hide {f.occlusion_predicted:.2f} of "
                f"fruit {i} from camera0 (tolerance {OCCLUSION_TOLERANCE}; other leaves count "
                f"too: occluders {f.occluders}); raise the occlusion or move the fruit")
    return MultiPlantModel(branches=branches, fruits=fruits, leaves=leaves, p_WC=p_WC)


def LeafLeafPenetration(leaves_V: list, tets: list) -> np.ndarray:
    """(L, L) matrix: how deep (m, >= 0) the vertices of leaf a lie inside
    leaf b's closed surface (0 when apart), for leaf vertex arrays at any
    configuration (rest or simulated)."""
    n = len(leaves_V)
    out = np.zeros((n, n))
    surfs = [trimesh.Trimesh(V, BoundaryTriangles(T), process=False)
             for V, T in zip(leaves_V, tets)]
    for a in range(n):
        for b in range(n):
            if a != b:
                out[a, b] = max(0.0, -float(SurfaceDistance([surfs[b]], leaves_V[a]).min()))
    return out
