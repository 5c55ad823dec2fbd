"""The planner's inputs (``PlanningContext``): the scene estimate, the camera
pose, the robot and its joints, with what the checks need derived once (the
fruits' SDF and box, the branch distance, the occluders). World frame W,
metres."""
from __future__ import annotations

import dataclasses as dc

import numpy as np
import trimesh

from lmap_drake.planning.collision import BranchDistance, UnionSdf
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
        self.fruit_sdf = fruit.sdf_W if fruit is not None else None
        self.fruit_box = ((fruit.vertices_W.min(0), fruit.vertices_W.max(0))
                          if fruit is not None else None)
        # Several fruits: the robot and the moved leaf keep clear of every
        # one (the union's SDF is the minimum); only the target is revealed.
        others = [f for f in getattr(self.scene, "other_fruits", []) if f is not None]
        if fruit is not None and others:
            fruits = [fruit] + others
            self.fruit_sdf = UnionSdf([f.sdf_W for f in fruits],
                                      [(f.vertices_W.min(0), f.vertices_W.max(0))
                                       for f in fruits])
            V = np.vstack([f.vertices_W for f in fruits])
            self.fruit_box = (V.min(0), V.max(0))
        self.other_leaves_W = np.asarray(getattr(self.scene, "other_leaves_W", np.zeros((0, 3))),
                                         float).reshape(-1, 3)
        # What hides the target besides the leaf being moved (and the robot):
        # the branches, the other leaves and the other fruits.
        self.occluders_W = np.vstack([self.branch_obs_W, self.other_leaves_W]
                                     + [f.vertices_W for f in others])
        self.branch_box = ((branch.vertices_W.min(0), branch.vertices_W.max(0))
                           if branch is not None and len(branch.vertices_W) else None)
        self.p_WC = np.asarray(self.X_WC, float)[:3, 3]


def FruitSurfaceSamples(f) -> np.ndarray:
    """Even samples of a ``FruitEstimate``'s surface plus its vertices (W, m)."""
    mesh = trimesh.Trimesh(f.vertices_W, f.faces, process=False)
    pts, _ = trimesh.sample.sample_surface_even(mesh, 6000, seed=0)
    return np.vstack([pts, f.vertices_W])
