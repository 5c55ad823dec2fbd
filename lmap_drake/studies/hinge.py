"""How far the planner's hinge estimate is from the true petiole attachment.

For a run folder (``lmap-drake run`` or ``run --plan-only`` in simulation:
its recording, ``ground_truth.json`` and ``leaf_<j>_rest_W.obj``), the
plant estimate of view 0 is rebuilt as the run's diagram builds it, and
for every leaf instance the planner could grasp: the hinge estimate
(``planning.attachment.EstimateHinge``), the unseen petiole
(``UnseenPetiole``), the hinge error the misfit veto assumes (the larger of
the two and ``planner.hinge_error``), and the true leaf holding most of the
instance's points with its attachment. World frame W, metres (the rows:
centimetres).
"""
from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from lmap_drake.deformation.config import DeformationConfig
from lmap_drake.deformation.graph import MainLeafComponent
from lmap_drake.diagram import EpisodeResources, MakeReplayDiagram
from lmap_drake.errors import InputError
from lmap_drake.perception.recording import LoadRecording
from lmap_drake.planning.attachment import EstimateHinge, UnseenPetiole
from lmap_drake.planning.context import PlanningContext
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.planning.targets import TargetScene
from lmap_drake.scenario import LoadScenario, ScenarioWithCamera
from lmap_drake.systems.view_recorder import RecordedViews

MIN_POINTS = 100     # instances with fewer main-part points are not grasped
MATCH_MEDIAN = 0.01  # m: an instance is a true leaf's when its points' median distance is under


def HingeRows(leaf_sets: list, branch_sets: list, attach_W: list, surfaces_W: list,
              dcfg: DeformationConfig, hinge_error: float) -> list[dict]:
    """One row per leaf instance: ``leaf_sets[i]`` its points and
    ``branch_sets[i]`` the branch points the planner sees with it (W, m);
    ``attach_W[j]`` and ``surfaces_W[j]`` (vertices) the true leaves. Rows:
    instance, points, true leaf (None: no true leaf within
    ``MATCH_MEDIAN``), its share of the points, the leaves holding a fifth
    or more, the estimate's error, the unseen petiole and the assumed
    error (cm), and whether the assumed error covers the true one."""
    trees = [cKDTree(np.asarray(v, float)) for v in surfaces_W]
    rows = []
    for i, (leaf, branch) in enumerate(zip(leaf_sets, branch_sets)):
        leaf = np.asarray(leaf, float).reshape(-1, 3)
        main = leaf[MainLeafComponent(leaf, dcfg)] if len(leaf) else leaf
        if len(main) < MIN_POINTS or len(branch) == 0 or not trees:
            continue
        hinge = EstimateHinge(leaf, branch, dcfg)
        unseen = UnseenPetiole(leaf, hinge, dcfg)
        assumed = max(hinge_error, unseen)
        dist = np.stack([t.query(main)[0] for t in trees])
        owner = np.argmin(dist, axis=0)
        count = np.bincount(owner, minlength=len(trees))
        j = int(np.argmax(count))
        row = {"instance": i, "points": int(len(main)), "unseen_petiole_cm": round(unseen * 100, 1),
               "assumed_error_cm": round(assumed * 100, 1), "true_leaf": None}
        if np.median(dist[j][owner == j]) <= MATCH_MEDIAN:
            err = float(np.linalg.norm(hinge - np.asarray(attach_W[j], float)))
            row.update(true_leaf=j, share=round(float(count[j] / len(main)), 2),
                       leaves=[int(k) for k in np.flatnonzero(count >= 0.2 * len(main))],
                       error_cm=round(err * 100, 1), covered=bool(err <= assumed + 1e-9))
        rows.append(row)
    return rows


def Summary(rows: list[dict]) -> dict:
    """Over the matched rows: how many, median and largest error (cm), the
    share the assumed error covers, and the same for single-leaf instances."""
    m = [r for r in rows if r["true_leaf"] is not None]
    single = [r for r in m if len(r["leaves"]) == 1]

    def stats(rs):
        if not rs:
            return {"instances": 0}
        e = [r["error_cm"] for r in rs]
        return {"instances": len(rs), "median_error_cm": float(np.median(e)),
                "max_error_cm": float(np.max(e)),
                "covered": round(sum(r["covered"] for r in rs) / len(rs), 3)}
    return {"matched": stats(m), "single_leaf": stats(single),
            "merged": len(m) - len(single), "unmatched": len(rows) - len(m)}


def RunHinges(run_dir: str | Path, scenario_text: str = "{}") -> dict:
    """``HingeRows`` and ``Summary`` for view 0 of the simulated run in
    ``run_dir`` (the run's own scenario, ``scenario_text`` applied last)."""
    run = Path(run_dir)
    gt_file = run / "ground_truth.json"
    if not gt_file.exists():
        raise InputError(f"{gt_file} not found: the hinge study needs a simulated run folder")
    gt = json.loads(gt_file.read_text())
    rec = LoadRecording(run)
    s = LoadScenario(filename=str(run / "scenario.yaml"), scenario_text=scenario_text, bare=True)
    s = ScenarioWithCamera(s, rec.camera, rec.X_WC)
    res = EpisodeResources.Make(s, lambda *a: None)
    diagram = MakeReplayDiagram(s, res, RecordedViews(rec.views, 1))
    ctx = diagram.CreateDefaultContext()
    diagram.GetInputPort("status").FixValue(ctx, SimpleNamespace(targets=[], plan=None,
                                                                 initial_estimate=None))
    completion = diagram.GetSubsystemByName("shape_completion")
    robot = RobotModel(s.robot.X_WB.GetDeterministicValue())
    X_WC = s.cameras["camera0"].X_PB.GetDeterministicValue().GetAsMatrix4()
    plant = completion.GetOutputPort("plant_estimate").Eval(completion.GetMyContextFromRoot(ctx))
    attach, surfaces = [], []
    for lf in gt["leaves"]:
        mesh = run / f"leaf_{lf['index']}_rest_W.obj"
        if mesh.exists():     # static greenhouse leaves have no rest mesh
            attach.append(lf["leaf_attach_W"])
            surfaces.append(np.asarray(trimesh.load(mesh, force="mesh").vertices))
    ids = np.asarray(plant.semantic.leaf_instance)
    leaf_sets, branch_sets, kept = [], [], []
    for j in sorted(set(ids[ids >= 0].tolist())):
        scene = TargetScene(plant, 0, j) if plant.fruits else None
        if scene is None:
            break
        pc = PlanningContext(scene, X_WC, robot, np.asarray(s.robot.initial_q, float))
        leaf_sets.append(scene.semantic.leaf_points_W)
        branch_sets.append(pc.branch_all_W)
        kept.append(j)
    rows = HingeRows(leaf_sets, branch_sets, attach, surfaces, s.deformation,
                     s.planner.hinge_error)
    for r in rows:
        r["instance"] = kept[r["instance"]]
    return {"run": str(run), "rows": rows, "summary": Summary(rows)}
