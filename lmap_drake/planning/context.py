"""The planner's inputs (``PlanningContext``): the scene estimate, the camera
pose, the robot and its joints, with what the checks need derived once (the
fruits' SDF and box, the branch distance, the occluders). World frame W,
metres."""
from __future__ import annotations

import dataclasses as dc
from functools import cached_property

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from lmap_drake.planning.collision import BranchDistance, FruitSetSdf, UnionSdf
from lmap_drake.planning.config import FRUIT_SET_PAD
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.types import SceneEstimate


@dc.dataclass
class PlanningContext:
    """Inputs shared by the planners: the scene estimate, the camera pose
    ``X_WC`` (4x4), the robot model and its current joints."""
    scene: SceneEstimate
    X_WC: np.ndarray
    robot: RobotModel
    q_current: np.ndarray
    # camera0's field of view as tangents (x_min, x_max, y_min, y_max) of the
    # optical frame; None = unbounded. Bounds the visibility model's grid.
    image_tan: tuple | None = None
    # the fruit's points observed in earlier views (W, m; a second reveal of
    # the same fruit): the surface they show counts as seen before any
    # action, so an action scores by what no view has shown (N_vis)
    seen_before_W: np.ndarray | None = None
    # the fruit shapes the robot-fruit and leaf-fruit checks keep clear of
    # (``planner.fruit_shapes``): 'union' = each fruit's estimate and its
    # kept shape hypotheses (``collision.FruitSetSdf``), 'estimate' = the
    # estimates alone
    fruit_shapes: str = "union"
    # what the plans of one target's leaves share, computed once
    # (``TargetShared``: the fruits' obstacle, the target's visibility
    # surfaces); None: computed here
    shared: dict | None = None

    def __post_init__(self):
        sem = self.scene.semantic
        self.leaf_W = np.asarray(sem.leaf_points_W, float)
        self.branch_obs_W = np.asarray(sem.branch_points_W, float)
        branch = self.scene.branch
        self.branch_all_W = (np.vstack([self.branch_obs_W, branch.samples_W])
                             if branch is not None and len(branch.samples_W) else self.branch_obs_W)
        self.branch_distance = (BranchDistance(branch.vertices_W, branch.faces)
                                if branch is not None and len(branch.faces) else None)
        fruit = self.scene.fruit
        others = [f for f in getattr(self.scene, "other_fruits", []) if f is not None]
        # Several fruits: the robot and the moved leaf keep clear of every
        # one (the union's SDF is the minimum); only the target is revealed.
        # Each fruit's obstacle is built once here, for every check of the plan.
        self.fruit_sdf, self.fruit_box = (
            self.shared["fruit_obstacle"] if self.shared else
            FruitObstacle(([fruit] if fruit is not None else []) + others, self.fruit_shapes))
        self.other_leaves_W = np.asarray(getattr(self.scene, "other_leaves_W", np.zeros((0, 3))),
                                         float).reshape(-1, 3)
        # What hides the target besides the leaf being moved (and the robot):
        # the branches, the other leaves and the other fruits.
        self.occluders_W = np.vstack([self.branch_obs_W, self.other_leaves_W]
                                     + [f.vertices_W for f in others])
        self.branch_box = ((branch.vertices_W.min(0), branch.vertices_W.max(0))
                           if branch is not None and len(branch.vertices_W) else None)
        self.p_WC = np.asarray(self.X_WC, float)[:3, 3]

    @cached_property
    def branch_tree(self) -> cKDTree | None:
        """A KD-tree of ``branch_all_W`` (built when first needed, once per
        context); None without branch points."""
        return cKDTree(self.branch_all_W) if len(self.branch_all_W) else None


def TargetShared(scene: SceneEstimate, fruit_shapes: str) -> dict:
    """What every leaf's plan for ``scene``'s fruit shares (the scenes of
    ``targets.TargetScene`` differ in their leaves only), for
    ``PlanningContext.shared``: the fruits' obstacle (``FruitObstacle``)
    and the target's ``VisibilitySurfaces`` per shapes key, filled when
    first needed (``SurfacesOf``; deterministic: the same as computed per
    plan)."""
    fruit = scene.fruit
    others = [f for f in getattr(scene, "other_fruits", []) if f is not None]
    return {"fruit_obstacle": FruitObstacle(([fruit] if fruit is not None else []) + others,
                                            fruit_shapes),
            "visibility_surfaces": {}}


def SurfacesOf(ctx: PlanningContext, shapes: str):
    """``VisibilitySurfaces(ctx.scene.fruit, shapes)``, kept in
    ``ctx.shared`` (when given) for the target's other leaves."""
    if not ctx.shared:
        return VisibilitySurfaces(ctx.scene.fruit, shapes)
    kept = ctx.shared.setdefault("visibility_surfaces", {})
    if shapes not in kept:
        kept[shapes] = VisibilitySurfaces(ctx.scene.fruit, shapes)
    return kept[shapes]


def FruitObstacle(fruits: list, shapes: str = "union") -> tuple:
    """(sdf, box) of the fruits the checks keep clear of: the signed
    distance (m, W) to the nearest fruit and the box (lo, hi) of them all;
    with ``shapes`` 'union' each fruit is its estimate and its kept shape
    hypotheses (``collision.FruitSetSdf``), else its estimate alone. An SDF
    is evaluated only near its own box (``UnionSdf``; exact below
    ``FRUIT_SET_PAD`` with 'union', 5 cm else). (None, None) without
    fruits."""
    if not fruits:
        return None, None
    if shapes == "union":
        pad = FRUIT_SET_PAD
        parts = [FruitSetSdf(f, pad) for f in fruits]
    else:
        pad = 0.05
        parts = [(f.sdf_W, (f.vertices_W.min(0), f.vertices_W.max(0))) for f in fruits]
    if len(parts) == 1:
        return parts[0]
    lo = np.min([b[0] for _, b in parts], axis=0)
    hi = np.max([b[1] for _, b in parts], axis=0)
    return UnionSdf([sdf for sdf, _ in parts], [b for _, b in parts], pad), (lo, hi)


def NumShapes(fruit, shapes: str = "union") -> int:
    """How many shapes of ``fruit`` a check over ``shapes`` ('union' or
    'expected': the estimate and its kept hypotheses with a mesh; else the
    estimate) looks at."""
    if fruit is None:
        return 0
    hyp = getattr(fruit, "hypotheses", None)
    if shapes not in ("union", "expected") or hyp is None:
        return 1
    return 1 + sum(1 for f in hyp.faces[1:] if len(f))


def FruitShapesRecord(scene: SceneEstimate, fruit_shapes: str, visibility_shapes: str,
                      num_visibility_shapes: int | None) -> dict:
    """What a plan on ``scene`` checked and scored (``plan.json``'s
    ``fruit_shapes``): the two keys, the shapes the checks kept clear of
    (the target's, the other fruits' in all), the shapes the visibility
    averaged over, and the target's hypothesis intervals (volume cm^3, axis
    spread deg; None without hypotheses)."""
    fruit = scene.fruit
    others = [f for f in getattr(scene, "other_fruits", []) if f is not None]
    hyp = getattr(fruit, "hypotheses", None)
    return {"checks": fruit_shapes, "visibility": visibility_shapes,
            "num_checked_shapes": NumShapes(fruit, fruit_shapes),
            "num_checked_shapes_other_fruits": sum(NumShapes(f, fruit_shapes) for f in others),
            "num_visibility_shapes": num_visibility_shapes,
            "num_hypotheses_kept": None if hyp is None else len(hyp.vertices_W),
            "volume_interval_cm3": (None if hyp is None else
                                    np.round(np.asarray(hyp.volume_interval_cm3, float),
                                             2).tolist()),
            "axis_spread_deg": None if hyp is None else round(float(hyp.axis_spread_deg), 2)}


def MeshSurfaceSamples(vertices_W: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Even samples of a closed mesh's surface plus its vertices (W, m)."""
    mesh = trimesh.Trimesh(vertices_W, faces, process=False)
    pts, _ = trimesh.sample.sample_surface_even(mesh, 6000, seed=0)
    return np.vstack([pts, vertices_W])


def FruitSurfaceSamples(f) -> np.ndarray:
    """Even samples of a ``FruitEstimate``'s surface plus its vertices (W, m)."""
    return MeshSurfaceSamples(f.vertices_W, f.faces)


def VisibilitySurfaces(f, shapes: str = "expected"):
    """What the visibility model scores (``planner.visibility_shapes``):
    the estimate's surface samples, or with 'expected' and kept shape
    hypotheses a list of them, the estimate first, then each other kept
    hypothesis (``VisibilityModel`` then counts the mean over them)."""
    own = FruitSurfaceSamples(f)
    hyp = getattr(f, "hypotheses", None)
    if shapes != "expected" or hyp is None or len(hyp.vertices_W) <= 1:
        return own
    return [own] + [MeshSurfaceSamples(v, fc) for v, fc in zip(hyp.vertices_W[1:], hyp.faces[1:])
                    if len(fc)]
