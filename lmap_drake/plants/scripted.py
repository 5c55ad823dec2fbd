"""Scripted motions on the simulated plant world (``PlantWorldSim``),
without the planner: leaf points and tip grasp poses, approach and grasp,
a straight pull, the scripted pull of ``plant_scene.pull`` (``lmap-drake
run`` with ``pull``), and the oracle scene estimate (the simulator's ground
truth as an estimate, for planner tests and oracle ablations). World frame
W, metres, seconds.
"""
from __future__ import annotations

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix

from lmap_drake.plants.generator import MeshSignedDistance
from lmap_drake.plants.plant_sim import PlantWorldSim


def LeafPoint(world: PlantWorldSim, u: float, v: float, leaf: int = 0) -> tuple[int, np.ndarray]:
    """Index and current position of the mid-surface vertex of leaf ``leaf``
    nearest to leaf coordinates (u, v)."""
    uv = world.leaf_refs[leaf].uv
    n = len(uv) // 3
    idx = int(np.argmin(np.linalg.norm(uv[n:2 * n] - [u, v], axis=1))) + n
    return idx, world.LeafVertices(leaf)[idx]


def _LeafNormal(world: PlantWorldSim, leaf: int) -> np.ndarray:
    """Rest blade normal (toward the camera) of leaf ``leaf``."""
    return world.model.leaves[leaf].normal_W if world.multi else world.model.leaf_normal_W


def TipGraspPose(world: PlantWorldSim, from_tip: float, v: float,
                 leaf: int = 0) -> RigidTransform:
    """``X_WT`` for a grasp ``from_tip`` (m) from the blade tip, ``v`` (m) to
    the side of the midrib: pads closing across the blade (TCP y = current
    blade normal), approaching within the blade plane along the direction
    from the robot's shoulder to the grasp point (the natural reach)."""
    length = world.scenario.plant_scene.leaf.length
    if world.scenario.plant_scene.kind in ("greenhouse", "mesh_plant"):   # own lengths
        length = float(world.leaf_refs[leaf].uv[:, 0].max())
    u = length - from_tip
    _, p = LeafPoint(world, u, v, leaf)
    _, p_a = LeafPoint(world, u - 0.02, v, leaf)
    _, p_b = LeafPoint(world, u - 0.01, v + 0.01, leaf)
    n = np.cross(p_a - p, p_b - p)
    if np.linalg.norm(n) < 1e-12:    # a coarse leaf: two of the points are one vertex
        uv = world.leaf_refs[leaf].uv
        k = len(uv) // 3
        mid = world.LeafVertices(leaf)[k:2 * k]
        near = mid[np.argsort(np.linalg.norm(mid - p, axis=1))[:12]]
        n = np.linalg.svd(near - near.mean(axis=0))[2][2]   # the local plane's normal
    n /= np.linalg.norm(n)
    if n @ _LeafNormal(world, leaf) < 0:
        n = -n
    p_shoulder = world.X_WB.multiply(np.array([0.0, 0.0, 0.089159]))
    z = p - p_shoulder
    z -= (z @ n) * n
    z /= np.linalg.norm(z)
    x = np.cross(n, z)
    return RigidTransform(RotationMatrix(np.c_[x, n, z]), p)


def ApproachAndGrasp(world: PlantWorldSim, pull, leaf: int = 0) -> RigidTransform:
    """Moves to the pre-grasp pose, approaches, closes on leaf ``leaf`` and
    builds the grasp (``pull`` is a ``ScriptedPullConfig``). Returns the
    grasp ``X_WT``."""
    from lmap_drake.planning.motion import PlanApproach
    X_WT_grasp = TipGraspPose(world, pull.grasp_from_tip, pull.grasp_v, leaf)
    world.progress("planning the approach (IK)")
    plan = PlanApproach(world.robot, X_WT_grasp, world.q_cmd, _LeafNormal(world, leaf),
                        pull.pregrasp_distance, pull.pregrasp_opening)
    world.progress("moving to the pre-grasp pose")
    world.SetGripper(pull.pregrasp_opening, 0.0)
    world.MoveJoints([plan.via], speed_fraction=0.8)
    world.MoveJoints(plan.to_ready, speed_fraction=0.5)
    world.MoveJoints(plan.to_pregrasp, speed_fraction=0.5)
    world.progress("approaching")
    world.MoveJoints(plan.to_grasp, speed_fraction=0.15)
    world.progress("closing the gripper")
    world.CloseOnLeaf()
    world.Grasp()
    return X_WT_grasp


def Pull(world: PlantWorldSim, direction_W, distance: float, duration: float,
         hold: float = 0.0) -> None:
    """Moves the TCP in a straight line by ``distance`` (m) along
    ``direction_W`` in ``duration`` (s), keeping its orientation, then holds."""
    from lmap_drake.planning.motion import PlanPull, TimeJointPath
    d = np.asarray(direction_W, float)
    d /= np.linalg.norm(d)
    q_path = PlanPull(world.robot, world.X_WT(), distance * d, world.q_cmd)
    world.progress(f"pulling {distance * 100:.0f} cm")
    traj = TimeJointPath(world.time, world.q_cmd, q_path, 0.5, 0.01, duration)
    world.AdvanceTo(traj.end_time(), traj)
    if hold > 0:
        world.Hold(hold)


def RunScriptedPull(world: PlantWorldSim, settle: float = 0.3) -> dict:
    """Settle, observe, approach, grasp, pull and observe again with the
    scenario's ``plant_scene.pull``. Returns images before/after, the grasp
    and the outcome (``Outcome``)."""
    from lmap_drake.plants.outcome import Summarize

    cfg = world.scenario.plant_scene
    pull = cfg.pull
    world.progress("settling the plant")
    world.Hold(settle)
    before = world.Images()
    vis0 = world.Visibility()
    X_WT_grasp = ApproachAndGrasp(world, pull)
    Pull(world, pull.direction_W, pull.distance, pull.duration, pull.hold)
    after = world.Images()
    vis1 = world.Visibility()
    outcome = Summarize(world.samples, cfg.outcome, vis0, vis1)
    return {"before": before, "after": after, "outcome": outcome, "X_WT_grasp": X_WT_grasp}


def OracleSceneEstimate(world: PlantWorldSim, semantic):
    """A ``SceneEstimate`` whose fruit and branch are the simulator's ground
    truth (exact mesh, SDF, pose), around an observed ``semantic`` scene: for
    planner tests and oracle ablations, never for the pipeline itself."""
    import trimesh

    from lmap_drake.types import BranchEstimate, FruitEstimate, SceneEstimate

    m = world.model
    fruit = m.fruit_mesh_W
    est = FruitEstimate(vertices_W=np.asarray(fruit.vertices), faces=np.asarray(fruit.faces),
                        X_WO=m.X_WO, latent=np.zeros(0), center_W=m.fruit_center_W,
                        peduncle_axis_W=m.peduncle_axis_W,
                        sdf_W=lambda p: MeshSignedDistance(fruit, p))
    pts = m.branch_points_W
    tubes = [trimesh.creation.cylinder(m.branch_radius, segment=pts[i:i + 2], sections=16)
             for i in range(len(pts) - 1)]
    tube = trimesh.util.concatenate(tubes)
    samples, _ = trimesh.sample.sample_surface_even(tube, 3000, seed=0)
    branch = BranchEstimate(vertices_W=np.asarray(tube.vertices), faces=np.asarray(tube.faces),
                            samples_W=samples, axis_W=m.branch_axis_W)
    return SceneEstimate(semantic=semantic, branch=branch, fruit=est)
