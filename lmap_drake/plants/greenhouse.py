"""The generator of greenhouse sweet-pepper plants (``plant_scene.kind:
greenhouse``): 1-3 leaning, zig-zag main stems on strings, alternating
leaves at their nodes (ovate to lanceolate blades on petioles, size, curl
and droop drawn from the seed), fruits of every colour on short shoots and
curved stalks (the multi-fruit plant's fruit placement), leaves hung in
front of the placed fruits and tuned to their occlusion (the multi-fruit
plant's leaf tuning). Only the leaves that hide a target fruit from camera0,
then those hiding the other fruits, then those near a target, become FEM
leaves (at most ``greenhouse.max_fem_leaves``); the rest are static.

Pure function of the config (deterministic in ``greenhouse.seed``); world
frame W, metres.
"""
from __future__ import annotations

import dataclasses as dc
from types import SimpleNamespace

import numpy as np
from pydrake.geometry import Rgba

from lmap_drake.plants.config import FruitConfig, MultiFruitConfig
from lmap_drake.plants.generator import (BranchPointsAtHeights, PlantGenerationError,
                                         _leaf_vertices, _rot_about, _unit)
from lmap_drake.plants.greenhouse_model import (FRUIT_COLORS, GreenhouseConfigError,
                                                GreenhousePlantModel, StaticLeaf,
                                                ValidateGreenhouseConfig)
from lmap_drake.plants.leaf import OrientTets
from lmap_drake.plants.multi import FRUIT_GAP, OCCLUDER_MIN, Branch
from lmap_drake.plants.multi_generator import (_FruitViews, _Layout, _LeafFactory, _PlaceFruit,
                                               _TuneFruitLeaves)
from lmap_drake.plants.multi_geometry import BranchClearance, SurfaceDistance

SHOOT_RADIUS = 0.0035       # m, a fruit's side shoot
STRING_HEIGHT = 0.5         # m, the string runs this far above the stem top
LEAF_TRIES = 6
# the most FEM leaves a plant gets (greenhouse.fem_occluders: every leaf
# hiding a fruit, up to this many). At 8, 3 of 8 random greenhouse plants
# of seed 6464 (11-13 leaves hiding a fruit; default segmenter) ended at
# a grasp on a true occluder left static ("the pads hold leaf N, which
# this simulated plant models as static"); at 16 the one rerun
# (gh_random_6464_003, 11 hiding leaves) went on to reveal its fruits,
# safe, in 229 s. A leaf far from the arm sleeps (its FEM is not stepped),
# so an idle FEM leaf costs little. No greenhouse suite plant has more
# than 8 leaves hiding any part of a fruit.
MAX_FEM_LEAVES = 16


def GenerateGreenhousePlant(cfg, p_WC) -> GreenhousePlantModel:
    """Builds the greenhouse plant of ``cfg`` (a ``PlantSceneConfig`` with
    ``kind: greenhouse``) seen by camera0 at ``p_WC`` (m, W). Raises
    PlantGenerationError (naming the key) if it cannot be built as asked."""
    ValidateGreenhouseConfig(cfg)
    g = cfg.greenhouse
    rng = np.random.default_rng(g.seed)
    p_WC = np.asarray(p_WC, float)
    base = np.asarray(cfg.p_W_branch_base, float)
    to_cam = p_WC - base
    d_fwd = _unit([to_cam[0], to_cam[1], 0.0])
    e_lat = _unit(np.cross([0, 0, 1], d_fwd))
    covers = sum(f.cover_leaves for f in g.fruits)
    per_stem = np.full(g.num_stems, (g.num_leaves - covers) // g.num_stems)
    per_stem[:(g.num_leaves - covers) % g.num_stems] += 1
    stems, bases = _Stems(g, base, d_fwd, e_lat, per_stem, rng)
    branches = [Branch(f"stem_{s}", p, cfg.branch.radius, -1) for s, p in enumerate(stems)]
    fruits, mfcs, targets = _Fruits(cfg, stems, bases, branches, d_fwd, e_lat, rng)
    views = _FruitViews(fruits, branches, p_WC)
    fruit_meshes = [f.mesh_W for f in fruits]
    leaves, colors, blocked = _CoverLeaves(cfg, mfcs, fruits, branches, stems, views, d_fwd)
    _NodeLeaves(cfg, stems, per_stem, fruit_meshes, leaves, blocked, rng)
    colors += [None] * (len(leaves) - len(colors))
    surfs = [x.Surface() for x in leaves]
    occluders, occ_single, partial = [], [], []
    for i, f in enumerate(fruits):
        single = np.array([views[i].Occlusion([s]) for s in surfs])
        occ_single.append(single)
        most_first = np.argsort(-single)
        occluders.append([j for j in most_first if single[j] >= OCCLUDER_MIN])
        partial.append([j for j in most_first if 0.0 < single[j] < OCCLUDER_MIN])
    fem = _ChooseFem(g, targets, occluders, fruits, surfs, blocked, partial)
    order = fem + [j for j in range(len(leaves)) if j not in fem]
    new_index = {j: k for k, j in enumerate(order)}
    heights = np.array([x.attach_W[2] for x in leaves])
    for j in range(len(leaves)):
        colors[j] = _LeafColors(rng, g.leaf_color_variation,
                                (heights[j] - base[2]) / g.stem_length)
    for i, f in enumerate(fruits):
        f.occlusion_predicted = views[i].Occlusion(surfs)
        f.occluders = sorted(new_index[int(j)] for j in occluders[i])
        f.one_leaf_ceiling = max(
            [1.0 - views[i].Occlusion([s for k, s in enumerate(surfs) if k != j])
             for j in occluders[i]] or [1.0 - f.occlusion_predicted])
    static = []
    for j in order[len(fem):]:
        lf = leaves[j]
        static.append(StaticLeaf(surface_W=surfs[j], attach_W=lf.attach_W, shoot=lf.shoot,
                                 normal_W=lf.normal_W, color=colors[j][0],
                                 color_below=colors[j][1], uv=lf.uv))
    strings = [np.array([p[0] + [0, 0, -0.02], p[-1], p[-1] + [0, 0, STRING_HEIGHT]])
               for p in stems]
    return GreenhousePlantModel(
        branches=branches, fruits=fruits, leaves=[leaves[j] for j in fem], p_WC=p_WC,
        static_leaves=static, targets=targets, leaf_colors=[colors[j] for j in fem],
        strings_W=strings, num_stems=g.num_stems)


def _Stems(g, base, d_fwd, e_lat, per_stem, rng) -> tuple[list, list]:
    """Each stem's centre line (base, one point per node, top): leaning,
    bowed, zig-zagging a little at the nodes."""
    stems, bases = [], []
    for s in range(g.num_stems):
        b = base + e_lat * (s - 0.5 * (g.num_stems - 1)) * g.stem_spacing \
            + d_fwd * rng.uniform(-0.015, 0.015)
        lean = np.deg2rad(rng.uniform(0.3, 1.0) * g.lean_deg)
        side = s - 0.5 * (g.num_stems - 1)       # V-trained: outer stems lean outward
        out = np.sign(side) * e_lat if side else d_fwd * rng.choice([-1.0, 1.0])
        az = np.arctan2(out[1], out[0]) + rng.uniform(-0.5, 0.5)
        axis = np.array([np.sin(lean) * np.cos(az), np.sin(lean) * np.sin(az), np.cos(lean)])
        bow_dir = _unit(np.cross(axis, [np.cos(az + 1.3), np.sin(az + 1.3), 0.0]))
        bow = rng.uniform(-0.02, 0.02)
        n = int(per_stem[s]) + 2
        t = np.linspace(0, 1, n + 1)
        t[1:-1] += rng.uniform(-0.25, 0.25, n - 1) / n
        zig = np.r_[0.0, 0.004 * (-1.0) ** np.arange(n - 1), 0.0]
        zig_dir = _unit(np.cross(axis, bow_dir))
        pts = b + np.outer(t * g.stem_length, axis) + np.outer(bow * np.sin(np.pi * t), bow_dir) \
            + np.outer(zig, zig_dir)
        stems.append(pts)
        bases.append(b)
    return stems, bases


def _FruitCfg(color: str, rng, curved: bool = True) -> FruitConfig:
    """A pepper of the procedural family in ``color`` (immature ones smaller),
    on a curved stalk (``curved``; else a straight one: the multi-fruit
    plant's cover-leaf tuning attaches the leaves on its shoot, which a
    curved stalk brings too close to the fruit)."""
    f = FruitConfig()
    f.variant = ("blocky", "elongated", "conical")[int(rng.integers(3))]
    w = rng.uniform(0.06, 0.085) * (0.7 if color == "immature" else 1.0)
    f.size = [w, w * rng.uniform(0.9, 1.1), w * {"blocky": rng.uniform(0.9, 1.15),
                                               "elongated": rng.uniform(1.3, 1.7),
                                               "conical": rng.uniform(1.0, 1.35)}[f.variant]]
    f.lobes = int(rng.integers(3, 5))
    f.lobe_depth = float(rng.uniform(0.04, 0.14))
    f.squareness = float(rng.uniform(2.1, 2.8))
    f.cone = float(rng.uniform(0.25, 0.4)) if f.variant == "conical" else float(rng.uniform(0, 0.1))
    f.lobe_phase_deg = float(rng.uniform(0, 360))
    f.tilt_deg = float(rng.uniform(0, 15))
    f.tilt_azimuth_deg = float(rng.uniform(0, 360))
    c = np.clip(np.asarray(FRUIT_COLORS[color]) * rng.uniform(0.9, 1.08, 3), 0, 1)
    f.color = Rgba(*c, 1.0)
    f.stripe_color = Rgba(*(0.8 * c), 1.0)
    f.peduncle_curved = curved
    f.peduncle_length = float(rng.uniform(0.02, 0.035) if curved else rng.uniform(0.012, 0.02))
    f.peduncle_angle_deg = float(rng.uniform(20, 50))
    f.peduncle_azimuth_deg = float(rng.uniform(0, 360))
    f.peduncle_radius = 0.0035
    return f


def _Fruits(cfg, stems, bases, branches, d_fwd, e_lat, rng):
    """The placed fruits, then the random ones (clear of each other and of
    the other stems and shoots; a random fruit that does not fit is redrawn,
    up to 12 times, then left out). Appends one shoot per fruit to
    ``branches``; returns (fruits, their MultiFruitConfigs, target indices)."""
    g = cfg.greenhouse
    specs = [(k, f, False) for k, f in enumerate(g.fruits)] + \
        [(len(g.fruits) + k, None, True) for k in range(g.num_random_fruits)]
    fruits, mfcs, targets = [], [], []
    names = sorted(FRUIT_COLORS)
    for k, spec, random in specs:
        for attempt in range(12 if random else 1):
            if random:
                spec = SimpleNamespace(stem=int(rng.integers(g.num_stems)),
                                       height=float(rng.uniform(0.15, 0.7)),
                                       azimuth_deg=float(rng.uniform(-150, 150)), color="",
                                       cover_leaves=0, occlusion=0.0, target=False)
            color = spec.color or names[int(rng.integers(len(names)))]
            mfc = MultiFruitConfig(height=spec.height * g.stem_length, side=1.0,
                                   occlusion=spec.occlusion, num_leaves=spec.cover_leaves,
                                   shoot_extra=0.005, shoot_rise_deg=float(rng.uniform(10, 30)),
                                   fruit=_FruitCfg(color, rng, spec.cover_leaves == 0))
            a = np.deg2rad(spec.azimuth_deg)
            e_dir = np.cos(a) * d_fwd + np.sin(a) * e_lat
            key = f"plant_scene.greenhouse.fruits[{k}].height"
            try:
                fruit, shoot = _PlaceFruit(mfc, len(fruits), stems[spec.stem], bases[spec.stem],
                                           d_fwd, e_dir, cfg.branch.radius, SHOOT_RADIUS)
            except PlantGenerationError as err:
                if random:
                    continue
                raise GreenhouseConfigError(key, f"{spec.height}: {err.detail}") from None
            shoot_branch = Branch(f"shoot_{len(fruits)}", shoot, SHOOT_RADIUS, spec.stem)
            clash = _Clash(fruit, fruits, branches, spec.stem)
            if clash:
                if random:
                    continue
                raise GreenhouseConfigError(key, f"{spec.height} (stem {spec.stem}, azimuth "
                                            f"{spec.azimuth_deg} deg): {clash}; move the fruit")
            fruit.shoot = len(branches)
            fruit.occlusion_requested = float(spec.occlusion) if spec.cover_leaves else float("nan")
            branches.append(shoot_branch)
            if spec.target:
                targets.append(len(fruits))
            fruits.append(fruit)
            mfcs.append(mfc)
            break
    return fruits, mfcs, targets


def _Clash(fruit, fruits, branches, stem) -> str:
    """Why ``fruit`` does not fit beside the fruits and branches so far ("" if it does)."""
    for i, other in enumerate(fruits):
        if SurfaceDistance([other.mesh_W], fruit.mesh_W.vertices).min() < FRUIT_GAP:
            return f"it touches fruit {i}"
    for b, br in enumerate(branches):
        if b != stem and BranchClearance(fruit.mesh_W.vertices, br).min() < FRUIT_GAP:
            return f"it touches {br.name}"
    return ""


def _CoverLeaves(cfg, mfcs, fruits, branches, stems, views, d_fwd):
    """The leaves hung in front of the placed fruits, tuned to their
    occlusion (``multi_generator._TuneFruitLeaves`` on a multi-plant view of
    this plant). Returns (leaves, colours (None: drawn later), blocked)."""
    g = cfg.greenhouse
    lf = dc.replace(cfg.leaf, target_tets=g.fem_target_tets,
                    length=float(np.mean(g.leaf_length)) * 1.05,
                    width=float(np.mean(g.leaf_length)) * 1.05 * float(np.mean(g.leaf_aspect)))
    shim = SimpleNamespace(multi=SimpleNamespace(fruits=mfcs, shoot_radius=SHOOT_RADIUS,
                                                 leaf_gap=0.003), leaf=lf)
    lay = _Layout(cfg=shim, d_fwd=d_fwd, stem_pts=stems[0], branches=branches, fruits=fruits,
                  fruit_meshes=[f.mesh_W for f in fruits], views=views,
                  factory=_LeafFactory(lf, d_fwd, 0.003, cfg.leaf.min_fruit_clearance))
    placed: set = set()
    for i, mfc in enumerate(mfcs):
        if not mfc.num_leaves:
            continue
        idx = list(range(len(lay.leaves), len(lay.leaves) + mfc.num_leaves))
        lay.leaves.extend([None] * mfc.num_leaves)
        try:
            _TuneFruitLeaves(lay, i, idx, placed)
        except PlantGenerationError as err:
            raise GreenhouseConfigError(f"plant_scene.greenhouse.fruits[{i}].cover_leaves",
                                        err.detail) from None
    return lay.leaves, [None] * len(lay.leaves), set()


def _NodeLeaves(cfg, stems, per_stem, fruit_meshes, leaves, blocked, rng) -> None:
    """One leaf per stem node, alternating sides, each drawn (size, shape,
    droop, twist, curl) until it keeps ``leaf.min_fruit_clearance`` from
    every fruit (``LEAF_TRIES`` draws; a leaf that never does is kept and
    added to ``blocked``: it never becomes FEM)."""
    g, lc = cfg.greenhouse, cfg.leaf
    for s, pts in enumerate(stems):
        a0 = rng.uniform(0, 2 * np.pi)
        for k in range(int(per_stem[s])):
            node = pts[k + 1]
            az = a0 + np.pi * k + np.deg2rad(50) * np.sin(0.9 * k) + rng.uniform(-0.4, 0.4)
            best = None
            for attempt in range(LEAF_TRIES):
                leaf, margin = _NodeLeaf(g, lc, node, s, az + 0.35 * attempt * (-1) ** attempt,
                                         cfg.branch.radius, fruit_meshes, rng)
                if best is None or margin > best[1]:
                    best = (leaf, margin)
                if margin >= 0:
                    break
            if best[1] < 0:
                blocked.add(len(leaves))
            leaves.append(best[0])


def _NodeLeaf(g, lc, node, stem, az, stem_radius, fruit_meshes, rng):
    """A leaf at ``node`` toward azimuth ``az`` (rad): (MultiLeaf, clearance
    margin to the fruits, m)."""
    length = rng.uniform(*g.leaf_length)
    aspect = rng.uniform(*g.leaf_aspect)
    lf = dc.replace(lc, length=float(length), width=float(length * aspect),
                    shape="ovate" if aspect > 0.5 else "elliptic",
                    petiole_length=float(length * rng.uniform(0.25, 0.45)),
                    target_tets=g.fem_target_tets, element_size=0.0)
    droop = np.deg2rad(rng.uniform(*g.droop_deg))
    e_a = np.array([np.cos(az), np.sin(az), 0.0])
    rise = 0.5 * np.pi - droop
    p = _unit(np.cos(rise) * e_a + np.sin(rise) * np.array([0, 0, 1.0]))
    m = _rot_about(p, np.deg2rad(rng.uniform(-20, 20))) @ _unit(
        np.sin(rise) * e_a - np.cos(rise) * np.array([0, 0, 1.0]))
    factory = _LeafFactory(lf, p, 0.0, lc.min_fruit_clearance)
    attach = node + p * stem_radius * 0.5
    reach = 0.7 * lf.petiole_length + lf.bend_radius
    V = _leaf_vertices(factory.shape, factory.nodes, attach, p, m, reach, lf.bend_radius)
    # cupping across the blade and a drooping tip
    u, v = factory.nodes[:, 0], factory.nodes[:, 1]
    lat = _unit(np.cross(m, p))
    up = _unit(np.cross(m, lat))
    if up[2] < 0:
        up = -up
    blade = np.clip(u, 0, None)
    curl = g.curl * rng.uniform(0.5, 1.5)
    V = V + np.outer(curl * v ** 2 / max(lf.width, 1e-3), up) \
        + np.outer(-0.6 * curl * blade ** 2 / lf.length, [0, 0, 1.0])
    tets = OrientTets(V, factory.tets)
    margin = float(SurfaceDistance(fruit_meshes, V).min()) - lc.min_fruit_clearance \
        if fruit_meshes else np.inf
    leaf = factory.Leaf(V, tets, m, reach, attach, stem, -1, 0.0)
    return leaf, margin


def _ChooseFem(g, targets, occluders, fruits, surfs, blocked, partial=()) -> list[int]:
    """The FEM leaves: each target's occluders (most hiding first, the
    targets in turn), then the other fruits' occluders (a planner revealing
    every fruit moves those too: a static leaf cannot be grasped), then the
    leaves hiding less than ``OCCLUDER_MIN`` of a fruit (``partial``, per
    fruit, most hiding first: the planner's fruit shapes are larger than the
    true ones, so it may move such a leaf too), then the leaves within
    ``fem_radius`` of a target fruit's surface (nearest first); at most
    ``max_fem_leaves``, raised with ``fem_occluders`` to the number of
    leaves hiding any part of a fruit (at most ``MAX_FEM_LEAVES``); never a
    blocked leaf."""
    chosen: list[int] = []
    budget = g.max_fem_leaves
    if g.fem_occluders:
        hiding = {int(j) for o in list(occluders) + list(partial) for j in o
                  if j not in blocked}
        budget = max(budget, min(len(hiding), MAX_FEM_LEAVES))

    def take(j):
        if j not in chosen and j not in blocked and len(chosen) < budget:
            chosen.append(int(j))
    others = [i for i in range(len(fruits)) if i not in targets]
    for lists in [occluders] + ([partial] if g.fem_occluders and len(partial) else []):
        for group in (targets, others):
            for rank in range(max([len(lists[i]) for i in group] or [0])):
                for i in group:
                    if rank < len(lists[i]):
                        take(lists[i][rank])
    near = []
    for i in targets:
        for j, s in enumerate(surfs):
            d = float(SurfaceDistance([fruits[i].mesh_W], s.vertices).min())
            if d <= g.fem_radius:
                near.append((d, j))
    for _, j in sorted(near):
        take(j)
    return chosen


def _LeafColors(rng, variation: float, height: float) -> tuple:
    """(upper side, lower side) RGBA of one leaf: a green varied by
    ``variation``, lower (older) leaves darker and yellower, the lower side
    paler and greyer."""
    base = np.array([0.16, 0.42, 0.10]) * (0.85 + 0.3 * np.clip(height, 0, 1))
    old = np.clip(0.5 - height, 0, 0.5)
    base = base + old * np.array([0.12, 0.05, -0.02])
    c = np.clip(base * (1 + variation * rng.uniform(-1, 1, 3)), 0, 1)
    below = np.clip(0.55 * c + 0.45 * np.array([0.55, 0.66, 0.45]), 0, 1)
    return (float(c[0]), float(c[1]), float(c[2]), 1.0), \
        (float(below[0]), float(below[1]), float(below[2]), 1.0)
