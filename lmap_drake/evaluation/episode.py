"""One full LMAP episode in simulation: the complete Diagram on the FEM plant
world, the simulated grasp, ground-truth outcome measures and shape metrics.
World frame W, metres, seconds."""
from __future__ import annotations

import dataclasses as dc
import json
import time
from pathlib import Path
from typing import Callable

import numpy as np

from lmap_drake.diagram import EpisodeResources, MakeEpisodeDiagram
from lmap_drake.plants.outcome import Summarize
from lmap_drake.plants.simworld import PlantWorldSim
from lmap_drake.scenario import Scenario
from lmap_drake.station.camera_noise import CameraProfile


def ShapeErrors(estimate, model) -> dict | None:
    """Table I metrics of a fruit estimate against the ground truth: Chamfer
    (cm), volume error (cm^3), centre error (cm), peduncle-axis angle (deg)."""
    from lmap_drake.shape.metrics import ShapeMetrics
    if estimate is None or estimate.fruit is None:
        return None
    f = estimate.fruit
    gt = model.fruit_mesh_W
    return {k: float(v) for k, v in ShapeMetrics(
        f.vertices_W, f.faces, f.peduncle_axis_W, np.asarray(gt.vertices),
        np.asarray(gt.faces), model.peduncle_axis_W, n=10000).items()}


class LeafAnimator:
    """Meshcat's recording does not animate deformable bodies: this adds the
    leaf's surface as a triangle mesh every ``period`` simulated seconds and
    toggles the snapshots' visibility in the recording, so the saved HTML
    shows the leaf moving."""

    def __init__(self, meshcat, world: PlantWorldSim, period: float = 0.2):
        from lmap_drake.plants.leaf import BoundaryTriangles
        self.meshcat, self.world, self.period = meshcat, world, period
        self.faces = np.asarray(BoundaryTriangles(world.model.leaf_tets), np.int32).T.copy()
        self.k, self.next_time, self.previous = 0, 0.0, None

    def __call__(self) -> None:
        from pydrake.geometry import Rgba
        t = self.world.time
        if self.meshcat is None or t < self.next_time:
            return
        path = f"/leaf_snapshots/{self.k:04d}"
        V = np.asarray(self.world.LeafVertices().T, float, order="F")
        self.meshcat.SetTriangleMesh(path, V, np.asfortranarray(self.faces),
                                     Rgba(0.2, 0.6, 0.15, 1.0))
        self.meshcat.SetProperty(path, "visible", False, 0.0)
        self.meshcat.SetProperty(path, "visible", True, t)
        if self.previous is not None:
            self.meshcat.SetProperty(self.previous, "visible", False, t)
        self.previous, self.k, self.next_time = path, self.k + 1, t + self.period


@dc.dataclass
class EpisodeResult:
    """What ``RunEpisode`` returns (and writes as ``episode.json``)."""
    record: dict
    world: PlantWorldSim
    images_before: dict
    images_after: dict
    status: object


def RunEpisode(scenario: Scenario, meshcat=None, progress: Callable[[str], None] | None = None,
               max_time: float = 40.0, resources: EpisodeResources | None = None
               ) -> EpisodeResult:
    """Simulates one episode until the controller is done or aborted (or
    ``max_time`` simulated seconds)."""
    progress = progress or (lambda m: None)
    wall0 = time.perf_counter()
    resources = resources or EpisodeResources.Make(scenario, progress)
    resources.progress = progress

    def make(s, m, grasp):
        return MakeEpisodeDiagram(s, resources, m, grasp)
    world = PlantWorldSim(scenario, meshcat, progress, make_diagram=make)
    if world.model.occlusion_clamped:
        progress(f"warning: the leaf hides at most {world.model.occlusion_predicted:.2f} of the "
                 f"fruit, not the requested plant_scene.occlusion "
                 f"{world.model.occlusion_requested:.2f} (clamped; recorded in episode.json)")

    def controller():
        c = world.diagram.GetSubsystemByName("arm_controller")
        return c, c.GetMyContextFromRoot(world.context)
    animate = LeafAnimator(meshcat, world)
    before = vis0 = None
    sim_wall = 0.0
    grasp_error = diagram_error = ""
    try:
        world.AdvanceTo(0.25)
        animate()
        before = world.Images()
        vis0 = world.Visibility()
        while world.time < max_time:
            t0 = time.perf_counter()
            world.AdvanceTo(world.time + 0.05)
            sim_wall += time.perf_counter() - t0
            animate()
            c, cctx = controller()
            st = c.Status(cctx)
            if st.finished:
                break
            # The simulated grasp is made as the pads close on the leaf (opening
            # at most ``grasp_attach_opening``), before a fast squeeze can push
            # the thin FEM leaf out from between them; see simworld.Grasp.
            closing = st.mode == "close_gripper" and world.GripperWidth() <= \
                scenario.planner.grasp_attach_opening
            if (closing or st.mode == "grasp_wait") and not st.grasp_acknowledged:
                try:
                    world.Grasp()
                except RuntimeError as err:
                    grasp_error = str(err)
                    progress(f"aborted: {err}")
                    break
                c, cctx = controller()
                c.AcknowledgeGrasp(cctx)
    # A failure inside the Diagram outside the controller's own stage
    # handling (e.g. a Perception event, the plant) ends the episode with a
    # status and a message in episode.json, not a traceback.
    except Exception as err:  # noqa: BLE001
        diagram_error = (f"stage_error: diagram at t = {world.time:.2f} s: "
                         f"{type(err).__name__}: {' '.join(str(err).split())}")
        progress(f"aborted: {diagram_error}")
        if before is None:
            before, vis0 = world.Images(), world.Visibility()
    c, cctx = controller()
    st = c.Status(cctx)
    after = world.Images()
    vis1 = world.Visibility()
    outcome = Summarize(world.samples, scenario.plant_scene.outcome, vis0, vis1)
    plan = st.plan
    chosen = plan.chosen.Row() if plan is not None and plan.chosen is not None else None
    record = {
        "scenario": scenario.plant_scene.name or "default",
        "method": scenario.planner.method,
        "energy_weight": scenario.planner.energy_weight,
        "perception": {"segmenter": scenario.perception.segmenter,
                       "camera": CameraProfile(scenario.camera_noise)},
        "status": "aborted" if grasp_error or diagram_error else st.mode,
        "message": diagram_error or grasp_error or st.message,
        # ok | no_action_needed | no_fruit | no_feasible_action | stage_error
        "plan_status": "stage_error" if diagram_error else (
            plan.status if plan is not None else ("stage_error" if st.failed_stage else None)),
        "failed_stage": "diagram" if diagram_error else (st.failed_stage or None),
        "plant": {"occlusion_requested": world.model.occlusion_requested,
                  "occlusion_predicted": world.model.occlusion_predicted,
                  "occlusion_clamped": world.model.occlusion_clamped},
        "chosen_action": chosen,
        # The planner's own visibility model (voxels of the estimated fruit):
        # seen initially, at most (fruit alone) and after the chosen action.
        "predicted_visibility": None if plan is None or not plan.seen_max else {
            "initial": plan.seen_init / plan.seen_max,
            "chosen": (plan.chosen.seen / plan.seen_max
                       if plan.chosen is not None and plan.chosen.seen >= 0 else None)},
        "outcome": outcome.to_dict(),
        "shape_initial": ShapeErrors(st.initial_estimate, world.model),
        "shape_final": ShapeErrors(st.final_estimate, world.model),
        "stage_seconds": st.stage_seconds,
        "simulated_seconds": world.time,
        "simulation_wall_seconds": sim_wall,
        "wall_seconds": time.perf_counter() - wall0,
        "mode_log": st.mode_log,
    }
    return EpisodeResult(record, world, before, after, st)


def SaveEpisode(result: EpisodeResult, out: Path) -> list[str]:
    """Writes ``episode.json``, before/after images with the segmentation
    overlaid, the plan table, and the shape pictures."""
    from lmap_drake.evaluation.figures import SaveEpisodeFigures
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "episode.json").write_text(json.dumps(result.record, indent=2, default=float))
    files = ["episode.json"]
    if result.status.plan is not None:
        result.status.plan.SaveJson(out / "candidates.json")
        files.append("candidates.json")
    files += SaveEpisodeFigures(result, out)
    return files
