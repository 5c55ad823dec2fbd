"""Ground-truth outcome measures computed from the simulator's state (never
from the planner's model). World frame, metres, newtons."""
from __future__ import annotations

import dataclasses as dc

import numpy as np

from lmap_drake.labels import FRUIT, DecodeLabels, EncodeLabel
from lmap_drake.plants.leaf import MaxPrincipalStretch


@dc.dataclass
class OutcomeSample:
    """Measures at one instant."""
    strain_percentile: float
    petiole_force: float
    fruit_penetration: float      # max depth (m) of leaf vertices / robot inside the fruit
    fruit_contact_force: float    # N, contact force on the fruit geometry
    robot_contact_force: float = 0.0   # N, largest robot-robot or robot-branch contact
    t: float = 0.0                # s, simulated time of the sample
    # per FEM leaf j (its ground-truth index): (strain percentile, petiole
    # force N, robot contact force N on it) now; a frozen leaf as last measured
    leaf_loads: dict = dc.field(default_factory=dict)
    grasped_leaf: int | None = None   # the FEM leaf held by the pads now


@dc.dataclass
class Outcome:
    """The episode's outcome (``outcome.json``): booleans for the safety
    flags, floats for the visibilities and the worst strain measure."""
    leaf_damage: bool
    plant_hazard: bool
    fruit_collision: bool
    visibility_initial: float
    visibility_final: float
    max_strain_percentile: float
    max_petiole_force: float
    max_fruit_penetration: float
    max_fruit_contact_force: float
    max_robot_contact_force: float = 0.0   # diagnostic (no flag): arm on itself or a branch

    def to_dict(self) -> dict:
        return {k: (bool(v) if isinstance(v, (bool, np.bool_)) else float(v))
                for k, v in dc.asdict(self).items()}


def RobotLeafContactForces(contact_results, inspector, leaf_geometry_ids: list) -> dict:
    """Per FEM leaf j (``leaf_geometry_ids[j]``: its deformable geometry),
    the total contact force (N) the robot (arm or gripper geometries) puts
    on it now, from a MultibodyPlant's ``ContactResults``; leaves the robot
    does not touch are left out."""
    leaf_of = {g: j for j, g in enumerate(leaf_geometry_ids)}
    out: dict = {}
    for i in range(contact_results.num_deformable_contacts()):
        info = contact_results.deformable_contact_info(i)
        j = leaf_of.get(info.id_A())
        if j is None or not inspector.GetName(info.id_B()).startswith(("ur5::",
                                                                       "robotiq_2f85::")):
            continue
        out[j] = out.get(j, 0.0) + float(np.linalg.norm(info.F_Ac_W().translational()))
    return out


def LeafLoadRows(samples: list[OutcomeSample], cfg) -> list[dict]:
    """Per FEM leaf over ``samples`` (``OutcomeConfig`` ``cfg``): its
    largest petiole force (N, and when), blade strain percentile and robot
    contact force (N); ``grasped``: held by the pads at some sample;
    ``touched``: grasped or touched by the robot; ``brushed``: touched but
    never grasped; ``damaged``: past the leaf-damage or plant-hazard
    threshold. Sorted by leaf."""
    rows: dict = {}
    for x in samples:
        for j, (strain, force, contact) in x.leaf_loads.items():
            r = rows.setdefault(j, {"leaf": int(j), "max_petiole_force": 0.0,
                                    "max_petiole_force_t": None, "max_strain_percentile": 1.0,
                                    "max_robot_contact_force": 0.0, "grasped": False})
            if force > r["max_petiole_force"]:
                r["max_petiole_force"], r["max_petiole_force_t"] = float(force), float(x.t)
            r["max_strain_percentile"] = max(r["max_strain_percentile"], float(strain))
            r["max_robot_contact_force"] = max(r["max_robot_contact_force"], float(contact))
            r["grasped"] |= x.grasped_leaf == j
    for r in rows.values():
        r["touched"] = bool(r["grasped"] or r["max_robot_contact_force"] > 0.0)
        r["brushed"] = bool(r["touched"] and not r["grasped"])
        r["damaged"] = bool(r["max_strain_percentile"] > cfg.tear_stretch
                            or r["max_petiole_force"] > cfg.petiole_max_force)
    return [rows[j] for j in sorted(rows)]


def ConstrainedTetMask(tets: np.ndarray, constrained_vertices: np.ndarray) -> np.ndarray:
    """Tets touching any constrained vertex (bool per tet)."""
    mask = np.zeros(int(tets.max()) + 1, bool)
    mask[np.asarray(constrained_vertices, int)] = True
    return mask[tets].any(axis=1)


def StrainPercentile(rest: np.ndarray, current: np.ndarray, tets: np.ndarray,
                     excluded: np.ndarray, percentile: float,
                     stretch: np.ndarray | None = None) -> float:
    """``percentile`` of per-tet max principal stretch over tets not in
    ``excluded`` (the maximum always sits next to a constraint).
    ``stretch``: ``MaxPrincipalStretch(rest, current, tets)`` when known."""
    if stretch is None:
        stretch = MaxPrincipalStretch(rest, current, tets)
    keep = ~excluded
    return float(np.percentile(stretch[keep] if keep.any() else stretch, percentile))


def PetioleForce(rest: np.ndarray, current: np.ndarray, tets: np.ndarray,
                 attach_tets: np.ndarray, youngs_modulus: float,
                 cross_section: float, stretch: np.ndarray | None = None) -> float:
    """Axial force estimate (N) in the petiole at the branch: E * A * (s - 1)
    with s the median max principal stretch of the tets at the attachment
    (a linear-elastic bar of the petiole's cross-section). ``stretch``:
    ``MaxPrincipalStretch(rest, current, tets)`` of every tet, when known."""
    if stretch is not None:
        stretch = np.asarray(stretch)[attach_tets]
    else:
        stretch = MaxPrincipalStretch(rest, current, tets[attach_tets])
    return float(youngs_modulus * cross_section * max(0.0, np.median(stretch) - 1.0))


def VisibilityFraction(labels: list, unoccluded_fruit_pixels: int,
                       fruit: int | None = None) -> float:
    """The fruit's pixels in at least one of ``labels`` (label images or
    arrays of one fixed camera) over its pixels with the leaves and robot
    removed (clipped to [0, 1]); ``fruit``: that fruit instance's label
    (None: every fruit pixel). One label is one view's visibility."""
    if unoccluded_fruit_pixels <= 0 or not len(labels):
        return 0.0
    seen = None
    for label in labels:
        lab = np.asarray(getattr(label, "data", label))
        lab = lab.reshape(lab.shape[0], lab.shape[1])
        mask = (DecodeLabels(lab)[0] == FRUIT) if fruit is None \
            else (lab == EncodeLabel(FRUIT, fruit))
        seen = mask if seen is None else (seen | mask)
    return float(min(1.0, seen.sum() / unoccluded_fruit_pixels))


def Summarize(samples: list[OutcomeSample], cfg, visibility_initial: float,
              visibility_final: float) -> Outcome:
    """Applies the thresholds of ``cfg`` (an ``OutcomeConfig``) to the worst
    values seen over the episode."""
    s = max((x.strain_percentile for x in samples), default=1.0)
    f = max((x.petiole_force for x in samples), default=0.0)
    pen = max((x.fruit_penetration for x in samples), default=0.0)
    fc = max((x.fruit_contact_force for x in samples), default=0.0)
    rc = max((x.robot_contact_force for x in samples), default=0.0)
    return Outcome(
        leaf_damage=s > cfg.tear_stretch, plant_hazard=f > cfg.petiole_max_force,
        fruit_collision=(pen > cfg.fruit_penetration) or (fc > cfg.fruit_contact_force),
        visibility_initial=visibility_initial, visibility_final=visibility_final,
        max_strain_percentile=s, max_petiole_force=f, max_fruit_penetration=pen,
        max_fruit_contact_force=fc, max_robot_contact_force=rc)


def TruthFruitOfPoints(points_W: np.ndarray, label_image, K, X_WC: np.ndarray,
                       min_fraction: float = 0.5) -> tuple[int | None, float]:
    """Which true fruit a fruit instance's points are of: the points (W, m)
    projected into the render label image of the view they came from
    (intrinsics ``K`` with fx, fy, cx, cy; camera pose ``X_WC`` 4x4); the
    fruit instance most of them land on, and the fraction of them on any
    fruit. Fewer than ``min_fraction`` on a fruit: (None, fraction), a
    phantom (e.g. a stalk the segmenter took for a fruit)."""
    return TruthInstanceOfPoints(points_W, label_image, K, X_WC, FRUIT, min_fraction)


def TruthInstanceOfPoints(points_W: np.ndarray, label_image, K, X_WC: np.ndarray,
                          class_id: int, min_fraction: float = 0.5
                          ) -> tuple[int | None, float]:
    """``TruthFruitOfPoints`` for any class (``labels.LEAF``: which true
    leaf, by its ground-truth index, a leaf instance's points are of)."""
    p = np.asarray(points_W, float).reshape(-1, 3)
    cls, inst = DecodeLabels(np.asarray(getattr(label_image, "data", label_image)).squeeze())
    if len(p) == 0:
        return None, 0.0
    from lmap_drake.perception.points import ProjectPoints
    uv = ProjectPoints(p, K, X_WC)
    uv = np.round(uv[np.isfinite(uv[:, 0])]).astype(int)
    u, v = uv[:, 0], uv[:, 1]
    inside = (u >= 0) & (u < cls.shape[1]) & (v >= 0) & (v < cls.shape[0])
    c, i = cls[v[inside], u[inside]], inst[v[inside], u[inside]]
    if len(c) == 0:
        return None, 0.0
    on_fruit = c == class_id
    fraction = float(np.mean(on_fruit))
    if fraction < min_fraction:
        return None, fraction
    ids, counts = np.unique(i[on_fruit], return_counts=True)
    return int(ids[np.argmax(counts)]), fraction


def TruthFruitOfInstance(semantic, fruit_id, label_image, K):
    """``TruthFruitOfPoints`` of fruit instance ``fruit_id``'s points in
    ``semantic`` (a SemanticScene: a target's scene holds its own points
    only, a target without a chosen leaf the whole plant's; None = every
    fruit point); None when it has no points."""
    pts = np.asarray(semantic.fruit_points_W, float).reshape(-1, 3)
    inst = np.asarray(semantic.fruit_instance)
    if fruit_id is not None and len(inst) == len(pts):
        pts = pts[inst == fruit_id]
    if len(pts) == 0:
        return None
    return TruthFruitOfPoints(pts, label_image, K, semantic.X_WC)


def ShapeErrors(estimate, model) -> dict | None:
    """Table I metrics of a fruit estimate (``SceneEstimate``) against the
    plant's ground truth: Chamfer (cm), volume error (cm^3), centre error
    (cm), peduncle-axis angle (deg); None without a fruit estimate."""
    from lmap_drake.shape.metrics import ShapeMetrics
    if estimate is None or estimate.fruit is None:
        return None
    f = estimate.fruit
    gt = model.fruit_mesh_W
    return {k: float(v) for k, v in ShapeMetrics(
        f.vertices_W, f.faces, f.peduncle_axis_W, np.asarray(gt.vertices),
        np.asarray(gt.faces), model.peduncle_axis_W, n=10000).items()}


def FruitShapeErrors(fruit, gt_mesh, gt_axis) -> dict | None:
    """Table I metrics of one ``FruitEstimate`` against a ground-truth fruit
    mesh (W, m) and its peduncle axis; None without an estimate."""
    from lmap_drake.shape.metrics import ShapeMetrics
    if fruit is None:
        return None
    return {k: float(v) for k, v in ShapeMetrics(
        fruit.vertices_W, fruit.faces, fruit.peduncle_axis_W, np.asarray(gt_mesh.vertices),
        np.asarray(gt_mesh.faces), gt_axis, n=10000).items()}
