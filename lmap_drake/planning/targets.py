"""Plants with several fruits and leaves (paper Sec. III-F, and two leaves
over one fruit, the paper's future work): which leaves hide which fruit,
the scene the single-fruit planner sees for one (fruit, leaf) target, the
order in which fruits are revealed and which leaf is moved.

World frame W, metres. Visibility fractions are of the completed fruit's
surface voxels seen from the camera (``planning.visibility``).
"""
from __future__ import annotations

import dataclasses as dc
import itertools

import numpy as np
from scipy.spatial import cKDTree

from lmap_drake.planning.context import FruitSurfaceSamples, PlanningContext, TargetShared
from lmap_drake.planning.lmap import PlanLmap
from lmap_drake.planning.visibility import VisibilityModel
from lmap_drake.types import FruitEstimate, PlantEstimate, SceneEstimate, SemanticScene


def _Instances(ids: np.ndarray, min_points: int) -> list[int]:
    ids = np.asarray(ids)
    u, n = np.unique(ids[ids >= 0], return_counts=True)
    return [int(i) for i, c in zip(u, n) if c >= min_points]


def OccludingLeaves(fruit: FruitEstimate, plant: PlantEstimate, X_WC: np.ndarray,
                    voxel: float = 0.003, image_tan: tuple | None = None,
                    min_gain: float = 0.02, min_points: int = 30,
                    seen_before_W: np.ndarray | None = None) -> dict:
    """How much of ``fruit`` each leaf instance hides: the fruit's visible
    fraction with everything observed in place (``visible``) and, per leaf,
    the fraction gained if that leaf alone were gone (``gain``). Leaves
    gaining at least ``min_gain`` are its occluders, most hiding first.
    Occluders: every leaf, the branches and the plant's other fruits (their
    estimates). ``seen_before_W`` (W, m): the fruit's points observed in
    earlier views; then ``visible`` also counts the surface they showed and
    a leaf's ``gain`` only surface no view has shown
    (``VisibilityModel.Observed``), and the result carries them as
    ``seen_before_W`` for ``PlanTarget``."""
    sem = plant.semantic
    vis = VisibilityModel(X_WC, FruitSurfaceSamples(fruit), voxel, image_tan)
    n_max = int(vis.max_seen.sum())
    leaf_W = np.asarray(sem.leaf_points_W, float).reshape(-1, 3)
    leaf_id = np.asarray(sem.leaf_instance)
    rest = [np.asarray(sem.branch_points_W, float).reshape(-1, 3)]
    rest += [f.vertices_W for f in plant.fruits if f is not fruit]
    ids = _Instances(leaf_id, min_points)
    # The grid is global, so the depth buffer of a union of point sets is
    # the min of their buffers (``VisibilityModel.ZBuffer``): each leaf's
    # buffer once, and "every leaf but j" as the min of the buffers before
    # and after j (the same buffers as splatting those points, at one
    # splat of the plant instead of one per leaf).
    base = vis.ZBuffer(np.vstack(rest + [leaf_W[~np.isin(leaf_id, ids)]]))
    bufs = [vis.ZBuffer(leaf_W[leaf_id == j]) for j in ids]
    before = list(itertools.accumulate([base] + bufs, np.minimum))    # [base, +0, +0..1, ...]
    after = list(itertools.accumulate([np.full_like(base, np.inf)] + bufs[::-1],
                                      np.minimum))[::-1]             # [0.., 1.., ..., none]
    none = np.zeros((0, 3))
    known = vis.Seen(none, before[-1])
    if seen_before_W is not None:
        known = known | vis.Observed(seen_before_W)
    seen_all = int(known.sum())
    out = {"visible": seen_all / n_max if n_max else 0.0, "seen_max": n_max, "leaves": []}
    if seen_before_W is not None:
        out["seen_before_W"] = np.asarray(seen_before_W, float).reshape(-1, 3)
    if n_max == 0:
        return out
    for m, j in enumerate(ids):
        # a leaf's removal only adds seen voxels: the gain is what it hides
        # and nothing (no view) has shown
        without = np.minimum(before[m], after[m + 1])
        gain = int(np.count_nonzero(vis.Seen(none, without) & ~known)) / n_max
        if gain >= min_gain:
            out["leaves"].append({"leaf_id": j, "gain": float(gain)})
    out["leaves"].sort(key=lambda d: -d["gain"])
    return out


def TargetScene(plant: PlantEstimate, k: int, leaf_id: int | None) -> SceneEstimate:
    """The single-fruit planner's view of target ``k`` (``plant.fruits[k]``)
    moving leaf instance ``leaf_id``: that leaf is the one to grasp, every
    other leaf point is an obstacle and occluder (``other_leaves_W``), the
    other fruits are obstacles and occluders (``other_fruits``). ``leaf_id``
    None: no leaf to move (every leaf point is in ``other_leaves_W``)."""
    sem = plant.semantic
    leaf_W = np.asarray(sem.leaf_points_W, float).reshape(-1, 3)
    leaf_inst = np.asarray(sem.leaf_instance)
    fruit_W = np.asarray(sem.fruit_points_W, float).reshape(-1, 3)
    fruit_inst = np.asarray(sem.fruit_instance)
    mine_leaf = (leaf_inst == leaf_id) if leaf_id is not None else np.zeros(len(leaf_W), bool)
    mine_fruit = fruit_inst == plant.fruit_ids[k]
    target = dc.replace(sem, leaf_points_W=leaf_W[mine_leaf], leaf_instance=leaf_inst[mine_leaf],
                        fruit_points_W=fruit_W[mine_fruit],
                        fruit_instance=fruit_inst[mine_fruit],
                        flags=list(sem.flags))
    return SceneEstimate(semantic=target, branch=plant.branch, fruit=plant.fruits[k],
                         other_fruits=[f for m, f in enumerate(plant.fruits) if m != k],
                         other_leaves_W=leaf_W[~mine_leaf])


def SeparateMovedLeaves(semantic, moved_leaf_points_W: list, radius: float = 0.015,
                        min_points: int = 30, other_leaf_points_W: list | None = None):
    """Finds the leaves moved before in this view (instance ids are not kept
    between views). ``moved_leaf_points_W``: one (N, 3) array (W, m) per
    moved leaf, its points in the view its move was planned in; released, a
    leaf hangs back near its rest. ``other_leaf_points_W`` (optional, one
    array per moved leaf): the other leaves' points in that view. A point
    here is the moved leaf's when it lies within ``radius`` (m) of it and
    nearer to it than to those other leaves; its instance is the one holding
    most such points. Where that instance also holds at least half a leaf
    more (the moved blade and a touching one segmented as one), the rest
    becomes an instance of its own; an instance most of whose points are
    such points (the moved blade segmented in pieces) is the moved leaf too.
    Returns (the ``SemanticScene``, with such instances split; the moved
    leaves' instance ids)."""
    leaf_W = np.asarray(semantic.leaf_points_W, float).reshape(-1, 3)
    ids = np.asarray(semantic.leaf_instance).copy()
    if len(ids) != len(leaf_W) or not np.any(ids >= 0):
        return semantic, []
    moved, split = [], False
    others = other_leaf_points_W or [None] * len(moved_leaf_points_W)
    for pts, other in zip(moved_leaf_points_W, others):
        pts = np.asarray(pts, float).reshape(-1, 3)
        if len(pts) == 0:
            continue
        d = cKDTree(pts).query(leaf_W, distance_upper_bound=radius)[0]
        near = d <= radius
        other = np.zeros((0, 3)) if other is None else np.asarray(other, float).reshape(-1, 3)
        if len(other) and near.any():
            near[near] = d[near] < cKDTree(other).query(leaf_W[near])[0]
        held = ids[near & (ids >= 0)]
        if len(held) < min_points:
            continue
        u, n = np.unique(held, return_counts=True)
        j = int(u[np.argmax(n)])
        rest = (ids == j) & ~near
        if rest.sum() >= max(min_points, 0.5 * len(pts)):
            ids[rest] = ids.max() + 1
            split = True
        moved.append(j)
        moved += [int(i) for i, c in zip(u, n) if i != j and c >= min_points
                  and c >= 0.5 * np.count_nonzero(ids == i)]
    if split:
        semantic = dc.replace(semantic, leaf_instance=ids,
                              flags=list(semantic.flags) + ["moved_leaf_separated"])
    return semantic, sorted(set(moved))


def NextLeafOccluders(occluders: dict, moved: list[int], min_gain: float) -> dict | None:
    """A fruit revealed once and still hidden by another leaf: its
    ``OccludingLeaves`` without the leaves already moved, or None when none
    of the others alone hides at least ``min_gain`` of it. The part a leaf
    alone hides in this view was hidden in every earlier view too (that
    leaf never moved, the camera is fixed), so the gain is surface no view
    has shown yet."""
    rest = [d for d in occluders["leaves"] if d["leaf_id"] not in set(moved)]
    if not rest or rest[0]["gain"] < min_gain:
        return None
    return dict(occluders, leaves=rest)


def OrderTargets(visible: list[float], done_fraction: float = 0.95) -> list[int]:
    """The order in which fruits are revealed: the least visible first (the
    one the estimate knows least about gains most from a reveal, and an
    interrupted episode has spent its motions where they mattered most);
    fruits already ``done_fraction`` visible need no action and are left
    out. Ties keep the given order."""
    v = np.asarray(visible, float)
    return [int(k) for k in np.argsort(v, kind="stable") if v[k] < done_fraction]


def ChooseLeafPlan(options: list[tuple[int, object]], tolerance: float = 0.05
                   ) -> tuple[int | None, object | None, str]:
    """Which leaf to move when several hide the fruit: ``options`` are
    (leaf_id, PlanResult) pairs. Among the plans with a chosen action, the
    highest predicted visibility wins; plans within ``tolerance`` of it are
    compared by predicted energy per leaf node (the lower wins). Returns the
    leaf, its plan and the reason, in words."""
    ok = [(j, p) for j, p in options if getattr(p, "chosen", None) is not None and p.seen_max]
    if not ok:
        return None, None, "no leaf has a feasible action"

    def vis(p):
        return p.chosen.seen / p.seen_max

    def energy(p):
        e = p.chosen.EnergyPerNode()
        return np.inf if e is None else e

    best = max(vis(p) for _, p in ok)
    close = [(j, p) for j, p in ok if vis(p) >= best - tolerance]
    j, p = min(close, key=lambda jp: (energy(jp[1]), -vis(jp[1])))
    if len(ok) == 1:
        why = f"leaf {j}: the only leaf with a feasible action"
    else:
        others = ", ".join(f"leaf {i}: visibility {vis(q):.2f}, energy/node {energy(q):.2e}"
                           for i, q in ok if i != j)
        why = (f"leaf {j}: predicted visibility {vis(p):.2f} at energy/node {energy(p):.2e} "
               f"(others: {others}; within {tolerance:g} of the best visibility the lower "
               f"energy wins)")
    return j, p, why


@dc.dataclass
class TargetPlan:
    """The plan for one fruit of the plant: ``fruit_index`` into
    ``PlantEstimate.fruits`` (instance ``fruit_id``), its visible fraction
    before any motion (predicted from the estimates), its occluding leaves
    (``OccludingLeaves``), the leaf chosen and its plan, why (in words),
    and every (leaf, plan) option weighed."""
    fruit_index: int
    fruit_id: int
    visible: float
    occluders: list
    leaf_id: int | None = None
    plan: object = None
    why: str = ""
    options: list = dc.field(default_factory=list)


def PlanTarget(plant: PlantEstimate, k: int, X_WC: np.ndarray, robot, q_current: np.ndarray,
               cfg, dcfg, image_tan: tuple | None = None, max_leaves: int = 2,
               progress=None, occluders: dict | None = None) -> TargetPlan:
    """Plans the reveal of fruit ``k``: for each of its (at most
    ``max_leaves``) occluding leaves, the single-fruit LMAP planner on
    ``TargetScene`` (the rest of the plant as obstacles and occluders);
    ``ChooseLeafPlan`` picks the leaf. ``occluders``: fruit ``k``'s
    ``OccludingLeaves``, when already computed (``FruitOrder``)."""
    occ = occluders or OccludingLeaves(plant.fruits[k], plant, X_WC, cfg.visibility_voxel,
                                       image_tan, min_gain=cfg.min_visibility_gain)
    out = TargetPlan(k, plant.fruit_ids[k], occ["visible"], occ["leaves"])
    if occ["visible"] >= cfg.early_stop_fraction:
        out.why = f"already {occ['visible']:.0%} visible: no action needed"
        return out
    if not occ["leaves"]:
        out.why = "no leaf hides it (it is hidden by the branch or another fruit)"
        return out
    shared = None          # the leaves' plans share the fruits' obstacle and surfaces
    for d in occ["leaves"][:max_leaves]:
        scene = TargetScene(plant, k, d["leaf_id"])
        shared = shared or TargetShared(scene, cfg.fruit_shapes)
        ctx = PlanningContext(scene, X_WC, robot, np.asarray(q_current, float), image_tan,
                              seen_before_W=occ.get("seen_before_W"),
                              fruit_shapes=cfg.fruit_shapes, shared=shared)
        out.options.append((d["leaf_id"], PlanLmap(ctx, cfg, dcfg, progress)))
    out.leaf_id, out.plan, out.why = ChooseLeafPlan(out.options)
    return out


# A completed fruit instance is a target only if it is a plausible sweet
# pepper: its volume within the range of the crop (small immature fruit to
# the largest blocky peppers; cm^3) and its observed points on its surface
# (median distance, m: the fit's own surface-loss scale). A shaded leaf
# patch completed as a fruit fails one or the other; it stays an obstacle.
FRUIT_VOLUME_CM3 = (10.0, 600.0)
MAX_FRUIT_RESIDUAL = 0.004


def FruitImplausible(fruit: FruitEstimate, points_W: np.ndarray) -> str:
    """Why the completed ``fruit`` (observed ``points_W``, W, m) is not a
    plausible target, or "" when it is (``FRUIT_VOLUME_CM3``,
    ``MAX_FRUIT_RESIDUAL``)."""
    import trimesh
    vol = abs(float(trimesh.Trimesh(fruit.vertices_W, fruit.faces, process=False).volume)) * 1e6
    if not FRUIT_VOLUME_CM3[0] <= vol <= FRUIT_VOLUME_CM3[1]:
        return (f"completed volume {vol:.0f} cm^3 outside a pepper's "
                f"{FRUIT_VOLUME_CM3[0]:g}-{FRUIT_VOLUME_CM3[1]:g} cm^3")
    pts = np.asarray(points_W, float).reshape(-1, 3)
    if len(pts) and fruit.sdf_W is not None:
        r = float(np.median(np.abs(fruit.sdf_W(pts))))
        if r > MAX_FRUIT_RESIDUAL:
            return (f"its points lie {r * 1000:.1f} mm from the completed surface "
                    f"(median; at most {MAX_FRUIT_RESIDUAL * 1000:g} mm)")
    return ""


def FruitConfidence(plant: PlantEstimate, k: int) -> float | None:
    """The segmentation confidence of fruit ``k`` (``plant.fruit_ids[k]``'s
    entry of ``SemanticScene.fruit_confidence``); None when perception gave
    none."""
    conf = getattr(plant.semantic, "fruit_confidence", None) or {}
    return conf.get(int(plant.fruit_ids[k])) if k < len(plant.fruit_ids) else None


def LowConfidence(confidence: float | None, min_confidence: float) -> str:
    """Why a fruit instance of segmentation ``confidence`` is no target
    (below ``planner.min_fruit_confidence``), or "" (it is one; no
    confidence: taken as a fruit)."""
    if confidence is None or not confidence < min_confidence:
        return ""
    why = ("segmentation confidence 0 (its border continues a leaf's surface: a "
           "patch of leaf, perception.fruit_leaf_patches)" if confidence == 0.0
           else f"segmentation confidence {confidence:.2f}")
    return f"{why} below planner.min_fruit_confidence {min_confidence:g}"


def LargestFruitSkipped(scene: SceneEstimate, cfg) -> str:
    """``planner.targets: largest``: why the most-seen fruit instance of
    ``scene.semantic`` (the one shape completion completed) is no target
    (``LowConfidence``), or ""."""
    sem = scene.semantic
    inst = np.asarray(sem.fruit_instance)
    ids, counts = np.unique(inst[inst >= 0], return_counts=True)
    if len(ids) == 0 or scene.fruit is None:
        return ""
    j = int(ids[np.argmax(counts)])
    why = LowConfidence((getattr(sem, "fruit_confidence", None) or {}).get(j),
                        getattr(cfg, "min_fruit_confidence", 0.0))
    return f"fruit instance {j} (the most seen) is no target: {why}" if why else ""


def FruitOrder(plant: PlantEstimate, X_WC: np.ndarray, cfg, image_tan: tuple | None = None
               ) -> tuple[list[int], list[dict]]:
    """The fruits' reveal order (``OrderTargets``: least visible first, the
    ones already visible left out, and the ones that are no target: a
    segmentation confidence below ``planner.min_fruit_confidence``
    (``LowConfidence``) or an implausible completed shape
    (``FruitImplausible``); their ``OccludingLeaves`` record carries
    ``implausible``, the reason) and every fruit's ``OccludingLeaves``
    (with ``confidence`` where perception gave one). Fruits that are no
    target stay obstacles and occluders of the others."""
    occ = [OccludingLeaves(f, plant, X_WC, cfg.visibility_voxel, image_tan,
                           min_gain=cfg.min_visibility_gain) for f in plant.fruits]
    sem = plant.semantic
    fruit_W = np.asarray(sem.fruit_points_W, float).reshape(-1, 3)
    inst = np.asarray(sem.fruit_instance)
    for k, f in enumerate(plant.fruits):
        conf = FruitConfidence(plant, k)
        if conf is not None:
            occ[k]["confidence"] = conf
        why = LowConfidence(conf, getattr(cfg, "min_fruit_confidence", 0.0))
        if not why:
            mine = fruit_W[inst == plant.fruit_ids[k]] if len(inst) == len(fruit_W) and \
                k < len(plant.fruit_ids) else fruit_W[:0]
            why = FruitImplausible(f, mine)
        if why:
            occ[k]["implausible"] = why
    order = OrderTargets([o["visible"] for o in occ], cfg.early_stop_fraction)
    return [k for k in order if "implausible" not in occ[k]], occ


def SkippedFruits(plant: PlantEstimate, occ: list[dict]) -> list[dict]:
    """The fruit instances ``FruitOrder`` left out as no target (JSON-able,
    for ``plan.json``): index, instance id, centre (W, m), segmentation
    confidence (None: none given) and why."""
    return [{"fruit_index": k, "fruit_id": int(plant.fruit_ids[k]) if k < len(plant.fruit_ids)
             else None, "center_W": np.round(plant.fruits[k].center_W, 4).tolist(),
             "confidence": o.get("confidence"), "why": o["implausible"]}
            for k, o in enumerate(occ) if "implausible" in o]


def HeldLeaf(semantic: SemanticScene, p_WT: np.ndarray, radius: float = 0.04) -> int:
    """The leaf in the gripper: the instance with the most points within
    ``radius`` (m) of the TCP at ``p_WT``, else (the pads hide the leaf
    there, and the robot self-filter drops what is next to them) the
    instance of the leaf point nearest the TCP; -1 without leaf points."""
    pts = np.asarray(semantic.leaf_points_W, float).reshape(-1, 3)
    ids = np.asarray(semantic.leaf_instance)
    if len(pts) == 0 or len(ids) != len(pts) or not np.any(ids >= 0):
        return -1
    pts, ids = pts[ids >= 0], ids[ids >= 0]
    d = np.linalg.norm(pts - p_WT, axis=1)
    near = d < radius
    if near.any():
        u, n = np.unique(ids[near], return_counts=True)
        return int(u[np.argmax(n)])
    return int(ids[np.argmin(d)])


def _SceneWithLeaf(scene: SceneEstimate, keep: np.ndarray) -> SceneEstimate:
    """``scene`` with the leaf points ``keep`` (bool mask) as its leaf and
    every other leaf point added to ``other_leaves_W`` (obstacles and
    occluders)."""
    sem = scene.semantic
    leaf_W = np.asarray(sem.leaf_points_W, float).reshape(-1, 3)
    ids = np.asarray(sem.leaf_instance)
    other = np.vstack([np.asarray(scene.other_leaves_W, float).reshape(-1, 3), leaf_W[~keep]])
    return dc.replace(scene, semantic=dc.replace(sem, leaf_points_W=leaf_W[keep],
                                                 leaf_instance=ids[keep],
                                                 flags=list(sem.flags)),
                      other_leaves_W=other)


def _LeafInstances(scene: SceneEstimate, min_points: int) -> list[int]:
    ids = np.asarray(scene.semantic.leaf_instance)
    n = len(np.asarray(scene.semantic.leaf_points_W).reshape(-1, 3))
    return _Instances(ids, min_points) if len(ids) == n else []


def OccluderScene(scene: SceneEstimate, X_WC: np.ndarray, cfg, image_tan: tuple | None = None,
                  min_points: int = 30) -> tuple[SceneEstimate, str]:
    """The single-fruit planner's scene on a plant of several leaves (as
    ``PlanTarget`` for several fruits): the leaf to grasp is the leaf
    instance that alone hides most of ``scene.fruit`` (``OccludingLeaves``),
    every other leaf point an obstacle and occluder. One leaf instance (or
    none, or no fruit): ``scene`` unchanged. Returns (scene, why): ``why``
    is non-empty when no leaf alone hides at least
    ``planner.min_visibility_gain`` of the fruit (nothing
    to move; the scene then has no leaf)."""
    inst = _LeafInstances(scene, min_points)
    if scene.fruit is None or len(inst) <= 1:
        return scene, ""
    plant = PlantEstimate(semantic=scene.semantic, branch=scene.branch,
                          fruits=[scene.fruit] + list(scene.other_fruits))
    occ = OccludingLeaves(scene.fruit, plant, X_WC, cfg.visibility_voxel, image_tan,
                          min_gain=cfg.min_visibility_gain, min_points=min_points)
    ids = np.asarray(scene.semantic.leaf_instance)
    if not occ["leaves"]:
        return _SceneWithLeaf(scene, np.zeros(len(ids), bool)), (
            f"no leaf alone hides the fruit ({len(inst)} leaves seen; it is "
            f"{occ['visible']:.0%} visible): nothing to move")
    return _SceneWithLeaf(scene, ids == occ["leaves"][0]["leaf_id"]), ""


def HeldLeafScene(scene: SceneEstimate, p_WT: np.ndarray, min_points: int = 30
                  ) -> SceneEstimate:
    """``scene`` with the leaf in the gripper (``HeldLeaf``, TCP at
    ``p_WT``, W, m) as its leaf and the other leaves as obstacles; one leaf
    instance or none: ``scene`` unchanged."""
    if len(_LeafInstances(scene, min_points)) <= 1:
        return scene
    j = HeldLeaf(scene.semantic, p_WT)
    return _SceneWithLeaf(scene, np.asarray(scene.semantic.leaf_instance) == j)
