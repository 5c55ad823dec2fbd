"""The generator of plants with several fruits and several leaves
(``plant_scene.kind: multi``): a main stem, one side shoot per fruit (the
fruit hangs from the shoot's end), leaves on the shoots (over their fruit)
and on the stem above the top fruit. Each leaf is its own two-layer tet
mesh with its petiole base fixed to its shoot or stem point.

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

import numpy as np
import trimesh

from lmap_drake.plants.generator import (OCCLUSION_CLAMP, OCCLUSION_TOLERANCE,
                                         BranchCenterline, BranchPointsAtHeights,
                                         OffsetBesideBranch, _leaf_vertices, _rot_about, _unit)
from lmap_drake.plants.leaf import (BoundaryTriangles, ExtrudeToTets, LeafShape, OrientTets,
                                    TriangulateLeaf)
from lmap_drake.plants.multi import (FRUIT_GAP, OCCLUDER_MIN, Branch, FileFruit,
                                     MultiConfigError, MultiFruit, MultiLeaf, MultiPlantModel,
                                     ValidateMultiConfig)
from lmap_drake.plants.multi_geometry import (BranchClearance, BranchTube, FruitView,
                                              LeafLeafGap, SurfaceDistance)
from lmap_drake.plants.pepper import MakePepper, PepperShapeOf


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

    def Leaf(self, V, tets, m, reach, attach, shoot, fruit, swing) -> MultiLeaf:
        """The ``MultiLeaf`` of a placed leaf (``Place``'s V, tets, midrib m
        and reach) on branch ``shoot`` over ``fruit`` (-1: a free leaf)."""
        lat = _unit(np.cross(m, self.d_fwd))
        normal = _unit(np.cross(m, lat))
        if normal @ self.d_fwd < 0:
            normal = -normal
        return MultiLeaf(rest_W=V, tets=tets, uv=self.nodes[:, :2].copy(),
                         fixed=self.fixed.copy(), attach_W=attach, shoot=shoot, fruit=fruit,
                         midrib_W=m, normal_W=normal, swing_deg=float(swing), reach=float(reach))

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
    PlantGenerationError (naming the key) if it cannot be built as asked:
    the fruits and their shoots, the free leaves on the stem, the leaves
    over each fruit tuned to its occlusion, then the occlusions recorded."""
    ValidateMultiConfig(cfg)
    p_WC = np.asarray(p_WC, float)
    base = np.asarray(cfg.p_W_branch_base, float)
    to_cam = p_WC - base
    d_fwd = _unit([to_cam[0], to_cam[1], 0.0])
    e_lat = _unit(np.cross([0, 0, 1], d_fwd))
    stem_pts = BranchCenterline(base, cfg.branch.length, cfg.branch.bend, e_lat)
    fruits, branches = _PlaceFruits(cfg, stem_pts, base, d_fwd, e_lat)
    lay = _Layout(cfg=cfg, d_fwd=d_fwd, stem_pts=stem_pts, branches=branches, fruits=fruits,
                  fruit_meshes=[f.mesh_W for f in fruits],
                  views=_FruitViews(fruits, branches, p_WC),
                  factory=_LeafFactory(cfg.leaf, d_fwd, cfg.multi.leaf_gap,
                                       cfg.leaf.min_fruit_clearance))
    _PlaceFreeLeaves(lay)
    _PlaceFruitLeaves(lay)
    _RecordOcclusions(lay)
    return MultiPlantModel(branches=branches, fruits=fruits, leaves=lay.leaves, p_WC=p_WC)


@dc.dataclass
class _Layout:
    """What the leaf placement works on (world frame, m): ``d_fwd`` the
    horizontal direction to camera0, the stem's centre line, the branches
    (the stem first), the fruits, camera0's view of each, the leaf factory,
    and the leaves placed so far (None: a slot not placed yet)."""
    cfg: object
    d_fwd: np.ndarray
    stem_pts: np.ndarray
    branches: list
    fruits: list
    fruit_meshes: list
    views: list
    factory: _LeafFactory
    leaves: list = dc.field(default_factory=list)


def _PlaceFruits(cfg, stem_pts, base, d_fwd, e_lat) -> tuple[list, list]:
    """The fruits and the branches (the stem, then one shoot per fruit);
    each fruit clear of the other fruits and of the other shoots."""
    mc = cfg.multi
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
    return fruits, branches


def _FruitViews(fruits: list, branches: list, p_WC: np.ndarray) -> list:
    """camera0's view of each fruit past the other fruits, the branches,
    the stalks and the peduncles."""
    fruit_meshes = [f.mesh_W for f in fruits]
    branch_meshes = [BranchTube(b) for b in branches] + [
        trimesh.creation.cylinder(f.stalk_radius, segment=f.stalk_W) for f in fruits] + [
        f.peduncle_mesh_W for f in fruits if f.peduncle_mesh_W is not None]
    return [FruitView(f.mesh_W, [m for k, m in enumerate(fruit_meshes) if k != i] +
                      branch_meshes, p_WC) for i, f in enumerate(fruits)]


def _PlaceFreeLeaves(lay: _Layout) -> None:
    """Free leaves on the stem above the top fruit's shoot, alternating
    sides (the first opposite the top fruit)."""
    cfg, mc, d_fwd = lay.cfg, lay.cfg.multi, lay.d_fwd
    stem_pts, branches, leaves = lay.stem_pts, lay.branches, lay.leaves
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
        V, tets, m, reach, ok = lay.factory.Place(attach, mc.free_leaf_swing_deg,
                                                  0.03 + 0.008 * k, side, lay.fruit_meshes,
                                                  branches, surfs, 0)
        if not ok:
            raise MultiConfigError("plant_scene.multi.num_leaves",
                                   f"({mc.num_leaves}): free leaf {k} cannot be placed clear of "
                                   f"the other leaves; use fewer leaves")
        leaves.append(lay.factory.Leaf(V, tets, m, reach, attach, 0, -1, mc.free_leaf_swing_deg))


def _PlaceFruitLeaves(lay: _Layout) -> None:
    """Leaves over the fruits, top fruit first; then a second pass re-tunes
    each fruit with every other leaf in place."""
    mc, leaves = lay.cfg.multi, lay.leaves
    slots: dict[int, list[int]] = {}
    order = sorted(range(len(lay.fruits)), key=lambda i: -mc.fruits[i].height)
    for i in order:
        fc = mc.fruits[i]
        slots[i] = []
        for k in range(fc.num_leaves):
            leaves.append(None)
            slots[i].append(len(leaves) - 1)
    placed = {j for j, x in enumerate(leaves) if x is not None}
    for _pass in range(2):
        for i in order:
            if slots[i]:
                _TuneFruitLeaves(lay, i, slots[i], placed)


def _TuneFruitLeaves(lay: _Layout, i: int, idx: list, placed: set) -> None:
    """Places fruit ``i``'s leaves (slots ``idx`` of ``lay.leaves``; one
    leaf swung sideways, two spread apart) at the swing whose occlusion of
    the fruit (with every other placed leaf) is nearest its requested
    ``occlusion``: a grid of swings, then bisection; the most they can hide
    if that is less."""
    mc, lf, d_fwd = lay.cfg.multi, lay.cfg.leaf, lay.d_fwd
    fruit_meshes, branches, leaves = lay.fruit_meshes, lay.branches, lay.leaves
    factory, views = lay.factory, lay.views
    fc, f = mc.fruits[i], lay.fruits[i]
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
            leaf = factory.Leaf(V, tets, m, reach, attach, f.shoot, i, swing)
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


def _RecordOcclusions(lay: _Layout) -> None:
    """Each fruit's occlusion by all leaves, its occluders and what one
    leaf's move can reveal; a fruit whose leaves miss the requested
    occlusion is clamped (a little less) or refused (naming the key)."""
    mc, views = lay.cfg.multi, lay.views
    surfs = [x.Surface() for x in lay.leaves]
    for i, (f, fc) in enumerate(zip(lay.fruits, mc.fruits)):
        f.occlusion_predicted = views[i].Occlusion(surfs)
        f.occluders = [j for j, s in enumerate(surfs) if views[i].Occlusion([s]) >= OCCLUDER_MIN]
        f.one_leaf_ceiling = max(
            [1.0 - views[i].Occlusion([x for k, x in enumerate(surfs) if k != j])
             for j in f.occluders] or [1.0 - f.occlusion_predicted])
        if not fc.num_leaves:
            continue
        target = float(fc.occlusion)
        miss = target - f.occlusion_predicted
        # The most the leaves can hide: the best grid value (_TuneFruitLeaves clamps there).
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
