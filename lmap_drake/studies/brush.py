"""How hard does the robot load a leaf it only brushes? The FEM plant world
against the planner's bound (``planner.max_brush_displacement``,
``planning.robot_checks.BrushPetioleForce``).

    python scripts/eval_brush.py --out out/brush.json

The single-leaf plant (``diagrams/default.yaml`` ``Defaults``, its FEM leaf:
E 10 MPa, 2 mm blade, 6 mm petiole) with the blade hung ``--clearance`` in
front of the fruit so that a push toward it does not reach the fruit. Per
blade point (``--points``: leaf coordinates u, v in m) and push depth
(``--depths``, m): the gripper, closed, comes in along the blade's normal
from the camera side at ``planner.approach_speed`` until its pads' tips
stand ``depth`` beyond the blade's rest surface, holds ``--hold`` s and
backs out. Each is one fork of the settled world. Rows: the planner's
predicted push at the deepest pose (``SheetPush`` over the blade's rest
vertices, the margin included), the lever (the point's distance to the
petiole's fixed vertices), the petiole load the beam model gives
(``BeamPetioleForce``) and the planner predicts (``BrushPetioleForce``,
its k calibrated on these rows), and what the plant world measured over the motion: the petiole force, the
blade strain percentile, the robot's contact force on the leaf.
"""
from __future__ import annotations

import dataclasses as dc
import json
from pathlib import Path

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix

from lmap_drake.paths import DEFAULT_SCENARIO_FILE
from lmap_drake.planning.motion import TimeJointPath
from lmap_drake.planning.robot_checks import (BeamPetioleForce, BrushPetioleForce, LeafNormals,
                                              SheetPush)
from lmap_drake.plants.outcome import LeafLoadRows
from lmap_drake.plants.plant_sim import PlantWorldSim
from lmap_drake.plants.scripted import LeafPoint, _LeafNormal
from lmap_drake.scenario import LoadScenario

PAD_TIP = 0.019     # m: the pads' tips beyond the TCP along its z (``RobotModel``)


@dc.dataclass
class BrushStudyOptions:
    """The study's settings (the flags of ``scripts/eval_brush.py``)."""
    out: str = ""
    points: list = dc.field(default_factory=lambda: [[0.10, 0.0], [0.06, 0.0], [0.03, 0.0]])
    depths: list = dc.field(default_factory=lambda: [0.005, 0.01, 0.015, 0.025])
    clearance: float = 0.08      # m: the blade this far in front of the fruit
    hold: float = 0.5            # s
    scenario_text: str = ""


def _Pose(world: PlantWorldSim, p: np.ndarray, n: np.ndarray, back: float) -> RigidTransform:
    """The closed gripper coming in along -``n`` (TCP z) with its pads'
    tips ``back`` (m) in front of ``p`` along ``n`` (negative: beyond it)."""
    z = -np.asarray(n, float)
    y = np.cross(z, [0.0, 0.0, 1.0])
    y = y / np.linalg.norm(y) if np.linalg.norm(y) > 1e-6 else np.array([0.0, 1.0, 0.0])
    x = np.cross(y, z)
    return RigidTransform(RotationMatrix(np.c_[x, y, z]), p - (PAD_TIP + back) * z)


def BrushOnce(settled: PlantWorldSim, uv, depth: float, hold: float) -> dict:
    """One push of ``depth`` (m) at leaf coordinates ``uv`` from a fork of
    ``settled`` (see the module docstring)."""
    world = settled.Fork()
    planner = world.scenario.planner
    idx, p = LeafPoint(world, float(uv[0]), float(uv[1]))
    rest = world.LeafVertices()
    n = np.asarray(_LeafNormal(world, 0), float)
    fixed = rest[np.flatnonzero(world.leaf_refs[0].fixed)]
    lever = float(np.linalg.norm(fixed - p, axis=1).min())
    X_in = _Pose(world, p, n, -depth)
    X_out = _Pose(world, p, n, 0.06)
    r_out = world.robot.Ik(X_out, world.q_cmd, 0.0, multistart=True)
    if not r_out.success:
        return {"uv": list(uv), "depth": depth, "error": "no IK for the pose in front"}
    r_in = world.robot.Ik(X_in, r_out.q, 0.0)
    if not r_in.success:
        return {"uv": list(uv), "depth": depth, "error": "no IK for the pushed pose"}
    normals = LeafNormals(rest)
    pts = world.robot.SurfacePointsByBody(r_in.q, 0.0)
    margin = planner.collision_margin
    touched = np.flatnonzero(pts.SignedDistance(rest, margin) < margin)
    push = (float(SheetPush(pts, rest[touched], normals[touched], margin, 0.08).max())
            if len(touched) else 0.0)
    t0 = len(world.samples)
    world.SetGripper(0.0, 0.3)
    world.MoveJoints([r_out.q], 0.5)
    start = len(world.samples)
    travel = 0.06 + depth
    for q0, q1 in ((r_out.q, r_in.q), (r_in.q, r_out.q)):
        traj = TimeJointPath(world.time, q0, [q1], 0.5, travel / planner.approach_speed)
        world.AdvanceTo(traj.end_time(), traj)
        if q1 is r_in.q:
            world.Hold(hold)
    rows = LeafLoadRows(world.samples[start:], world.scenario.plant_scene.outcome)
    row = rows[0] if rows else {}
    before = LeafLoadRows(world.samples[t0:start], world.scenario.plant_scene.outcome)
    return {"uv": [float(x) for x in uv], "vertex": idx, "depth": float(depth),
            "lever": round(lever, 4), "predicted_push": round(push, 4),
            "predicted_N": round(float(BrushPetioleForce(push, lever)), 3),
            "beam_N": round(BeamPetioleForce(push, lever,
                                             world.scenario.plant_scene.leaf.youngs_modulus,
                                             world.scenario.plant_scene.leaf.petiole_width,
                                             world.scenario.plant_scene.leaf.thickness), 3),
            "petiole_force_N": row.get("max_petiole_force"),
            "petiole_force_before_N": before[0]["max_petiole_force"] if before else None,
            "strain_percentile": row.get("max_strain_percentile"),
            "robot_contact_force_N": row.get("max_robot_contact_force"),
            "damaged": row.get("damaged")}


def RunBrushStudy(o: BrushStudyOptions, log=print) -> list[dict]:
    """Every (point, depth) of ``o``; the JSON list written to ``o.out``
    after each row (an interrupted study keeps the rows so far)."""
    text = "{plant_scene: {occlusion: 0.45, leaf: {clearance: %g}}}" % o.clearance
    scenario = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="Defaults",
                            scenario_text=o.scenario_text or text)
    world = PlantWorldSim(scenario)
    world.Hold(0.3)
    rows = []
    for uv in o.points:
        for d in o.depths:
            rows.append(BrushOnce(world, uv, d, o.hold))
            log(json.dumps(rows[-1]))
            if o.out:
                path = Path(o.out)
                tmp = path.with_suffix(".tmp")
                tmp.write_text(json.dumps(rows, indent=1))
                tmp.replace(path)
    return rows
