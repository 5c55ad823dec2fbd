"""Episodes: one runner for the simulated and the hardware station.

``RunEpisode`` builds the whole Diagram (``diagram.MakeEpisodeDiagram``)
around a station and steps it until the ``ArmController`` is finished:
observe, plan, [confirm], pre-grasp, approach, grasp, pull, hold, observe
again, fuse, re-estimate, release, retreat. What differs between the two
stations lives in a small *world* object:

- ``SimWorld`` (the FEM plant world, ``plants.simworld.PlantWorldSim``):
  simulated as fast as it goes; makes the grasp when the pads close on the
  leaf (a rebuilt station with the leaf fixed to the gripper) and undoes it
  at release; scores the outcome against the ground truth.
- ``HardwareWorld`` (``station.hardware``): steps the same Diagram against
  the wall clock (periodic events stand for time); a protective stop, an
  emergency stop, a lost link or a refused command ends the episode with
  the arm stopped and the gripper left as it is; no ground truth.

Every run writes what the planner saw (``perception.recording``), and
``ReplayRun`` re-plans offline on such a recording (``lmap-drake replay``).
Also here: the station snapshot and the scripted pull of ``lmap-drake run``.
World frame W, metres, seconds, radians.
"""
from __future__ import annotations

import dataclasses as dc
import json
import time
from pathlib import Path
from typing import Callable

import numpy as np
from pydrake.geometry import Meshcat
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from lmap_drake.diagram import EpisodeResources, MakeEpisodeDiagram
from lmap_drake.scenario import DumpScenario, Scenario
from lmap_drake.viz import SaveDepth, SaveLabel, SaveRgb


# --------------------------------------------------------------- snapshots
def RunStationSnapshot(scenario: Scenario, out: Path,
                       progress: Callable[[str], None] = print) -> list[str]:
    """Builds the simulated station with the scenario's plant, holds the arm
    at ``robot.initial_q`` for ``simulation_duration`` s, and writes
    ``scenario.yaml``, ``rgb.png``, ``depth.png`` (colour-mapped metres),
    ``label.png`` and ``scene.html`` (``kind: multi``: also the plant's
    ground truth, ``ground_truth.json`` with a ``fruits`` list, and meshes)."""
    from lmap_drake.plants.world import MakePlantStation
    out = Path(out)
    DumpScenario(scenario, out / "scenario.yaml")
    extra = []
    if scenario.plant_scene.kind == "multi":
        from lmap_drake.plants.multi import SaveMultiGroundTruth
        from lmap_drake.plants.world import GetPlantModel
        progress("generating the multi-fruit plant")
        extra = SaveMultiGroundTruth(GetPlantModel(scenario), out)
    progress("building station")
    meshcat = Meshcat()
    builder = DiagramBuilder()
    station = builder.AddNamedSystem("station", MakePlantStation(scenario, meshcat))
    q_hold = builder.AddNamedSystem("ur5_hold", ConstantVectorSource(scenario.robot.initial_q))
    builder.Connect(q_hold.get_output_port(), station.GetInputPort("ur5.position"))
    grip = builder.AddNamedSystem(
        "gripper_hold", ConstantVectorSource([scenario.robot.initial_gripper_width]))
    builder.Connect(grip.get_output_port(), station.GetInputPort("gripper.position"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    ApplySimulatorConfig(scenario.simulator_config, simulator)
    progress(f"simulating {scenario.simulation_duration:.2f} s")
    FrameMeshcat(meshcat, scenario)
    meshcat.StartRecording()
    simulator.AdvanceTo(scenario.simulation_duration)
    meshcat.StopRecording()
    meshcat.PublishRecording()
    context = station.GetMyContextFromRoot(simulator.get_context())
    progress("rendering camera0")
    SaveRgb(station.GetOutputPort("camera0.rgb_image").Eval(context), out / "rgb.png")
    SaveDepth(station.GetOutputPort("camera0.depth_image").Eval(context), out / "depth.png")
    SaveLabel(station.GetOutputPort("camera0.label_image").Eval(context), out / "label.png")
    (out / "scene.html").write_text(meshcat.StaticHtml())
    return ["scenario.yaml", "rgb.png", "depth.png", "label.png", "scene.html"] + extra


def RunScriptedPullEpisode(scenario: Scenario, out: Path,
                           progress: Callable[[str], None] = print) -> list[str]:
    """Procedural plant world: settle, observe, grasp and pull as given in
    ``plant_scene.pull``, observe again. Writes the snapshot files (before
    the pull), ``rgb_after.png``, ``label_after.png``, ``outcome.json``,
    the ground truth (``ground_truth.json``, ``fruit_W.obj``,
    ``leaf_rest_W.obj``) and ``scene.html`` (Meshcat recording; Meshcat's
    recording does not animate the deformable leaf)."""
    from lmap_drake.plants.generator import SaveGroundTruth
    from lmap_drake.plants.simworld import PlantWorldSim, RunScriptedPull

    out = Path(out)
    DumpScenario(scenario, out / "scenario.yaml")
    t0 = time.time()
    meshcat = Meshcat()
    progress("generating the plant and building the station")
    world = PlantWorldSim(scenario, meshcat, progress)
    files = ["scenario.yaml"] + SaveGroundTruth(world.model, out)
    FrameMeshcat(meshcat, scenario)
    meshcat.StartRecording()
    result = RunScriptedPull(world)
    meshcat.StopRecording()
    meshcat.PublishRecording()
    before, after = result["before"], result["after"]
    SaveRgb(before["rgb_image"], out / "rgb.png")
    SaveDepth(before["depth_image"], out / "depth.png")
    SaveLabel(before["label_image"], out / "label.png")
    SaveRgb(after["rgb_image"], out / "rgb_after.png")
    SaveLabel(after["label_image"], out / "label_after.png")
    outcome = result["outcome"].to_dict()
    record = dict(outcome)
    record["simulated_seconds"] = world.time
    record["wall_seconds"] = time.time() - t0
    (out / "outcome.json").write_text(json.dumps(record, indent=2))
    (out / "scene.html").write_text(meshcat.StaticHtml())
    progress(OutcomeLine(outcome))
    return files + ["rgb.png", "depth.png", "label.png", "rgb_after.png", "label_after.png",
                    "outcome.json", "scene.html"]


def FrameMeshcat(meshcat, scenario: Scenario) -> None:
    """Points the Meshcat camera at the plant and the arm (not the whole
    floor): the target is midway between the robot base and the camera's
    view of the plant, seen from behind the scenario camera."""
    if meshcat is None:
        return
    p_WB = scenario.robot.X_WB.GetDeterministicValue().translation()
    X_WC = scenario.cameras["camera0"].X_PB.GetDeterministicValue()
    p_WPlant = X_WC.translation() + 0.55 * X_WC.rotation().col(2)   # ~ the plant
    target = 0.5 * (p_WB + p_WPlant) + np.array([0.0, 0.0, 0.1])
    eye = X_WC.translation() - 0.6 * X_WC.rotation().col(2) + np.array([-0.4, 0.0, 0.35])
    try:
        meshcat.SetCameraPose(eye, target)
    except Exception:  # noqa: BLE001 - older Meshcat without SetCameraPose
        pass


# ------------------------------------------------------------------ worlds
class SimWorld:
    """The simulated plant world behind ``RunEpisode`` (see the module
    docstring)."""
    hardware = False

    def __init__(self, scenario: Scenario, resources: EpisodeResources, options,
                 meshcat=None, progress=None):
        from lmap_drake.plants.simworld import PlantWorldSim
        from lmap_drake.plants.world import MakePlantStation

        def make(s, m, grasp):
            diagram = MakeEpisodeDiagram(s, resources, MakePlantStation(s, m, grasp), options)
            return diagram, diagram.GetSubsystemByName("station")
        self.scenario = scenario
        self.sim = PlantWorldSim(scenario, meshcat, progress, make_diagram=make)
        self.model = self.sim.model
        self.progress = progress or (lambda m: None)
        self.animate = LeafAnimator(meshcat, self.sim)
        self.release_sample = None       # index into sim.samples where the release began
        self.vis_initial = None

    @property
    def diagram(self):
        return self.sim.diagram

    @property
    def context(self):
        return self.sim.context

    @property
    def time(self) -> float:
        return self.sim.time

    def Start(self) -> None:
        self.vis_initial = self.sim.Visibility()

    def Step(self, dt: float) -> None:
        self.sim.AdvanceTo(self.sim.time + dt)
        self.animate()

    def AfterStep(self, controller, cctx, st) -> str:
        """Makes the grasp as the pads close on the leaf (opening at most
        ``grasp_attach_opening``, before a fast squeeze can push the thin
        FEM leaf out) and undoes it at release. Returns an abort message or
        ''."""
        closing = st.mode == "close_gripper" and self.sim.GripperWidth() <= \
            self.scenario.planner.grasp_attach_opening
        if (closing or st.mode == "grasp_wait") and not st.grasp_acknowledged:
            try:
                self.sim.Grasp()
            except RuntimeError as err:
                return str(err)
            controller = self.diagram.GetSubsystemByName("arm_controller")
            controller.AcknowledgeGrasp(controller.GetMyContextFromRoot(self.context))
        if st.released and self.sim.grasp_state is not None:
            self.release_sample = len(self.sim.samples)
            self.sim.Release()
            self.progress("released the leaf")
        return ""

    def CurrentImages(self) -> dict:
        return self.sim.Images()

    def Pause(self) -> None:
        pass

    def Close(self) -> None:
        pass

    def Score(self, record: dict, views, st) -> None:
        """Ground truth: outcome flags (up to the release; the release and
        retreat separately), visibility in the two captured views (what the
        planner saw, and after the action), shape errors."""
        from lmap_drake.plants.outcome import ShapeErrors, Summarize
        sim = self.sim
        record["robot_contact"] = dict(sim.worst_robot_contact)   # what touched, if anything
        if getattr(sim, "multi", False):
            self._ScoreMulti(record, views, st)
            return
        if views and views[0].label is not None:     # what the planner saw
            self.vis_initial = sim.Visibility(views[0].label)
        if len(views) >= 2 and views[-1].label is not None:   # after the last motion
            vis_final = sim.Visibility(views[-1].label)
        else:
            vis_final = sim.Visibility()
        cut = self.release_sample if self.release_sample is not None else len(sim.samples)
        cfg = self.scenario.plant_scene.outcome
        record["outcome"] = Summarize(sim.samples[:cut], cfg, self.vis_initial,
                                      vis_final).to_dict()
        if self.release_sample is not None:
            after = Summarize(sim.samples[cut:], cfg, vis_final, sim.Visibility()).to_dict()
            record["release_outcome"] = {k: after[k] for k in (
                "plant_hazard", "fruit_collision", "max_petiole_force",
                "max_fruit_penetration", "max_fruit_contact_force")}
            record["release_outcome"]["visibility_after_release"] = after["visibility_final"]
        record["shape_initial"] = ShapeErrors(st.initial_estimate, self.model)
        record["shape_final"] = ShapeErrors(st.final_estimate, self.model)
        record["plant"] = {"occlusion_requested": self.model.occlusion_requested,
                           "occlusion_predicted": self.model.occlusion_predicted,
                           "occlusion_clamped": self.model.occlusion_clamped}
        record["simulated_seconds"] = sim.time


    def _ScoreMulti(self, record: dict, views, st) -> None:
        """Several fruits: the plant-level outcome over the whole episode
        (every grasp, motion, release and retreat) and one ``fruits`` entry
        per ground-truth fruit: its visibility in the first view and after
        its reveal (in the view observed after its last motion; unchanged
        when it was not moved for), the shape metrics of its estimate before
        and after, and the target record (leaf chosen, why, motions). A
        target is matched to the true fruit its points land on in the render
        labels of its view; a target whose points are mostly not on a fruit
        is a phantom (``targets[k].phantom``, ``phantom_targets``; e.g. a
        stalk segmented as fruit) and is no fruit's estimate."""
        from lmap_drake.plants.outcome import FruitShapeErrors, Summarize
        sim, model = self.sim, self.model
        label = [v.label for v in views]

        def vis(i, k):
            return sim.Visibility(label[k], fruit=i) if 0 <= k < len(label) and \
                label[k] is not None else sim.Visibility(fruit=i)
        def during(t):
            return [s for s in sim.samples
                    if t["t_start"] - 1e-9 <= s.t <= t["t_end"] + 1e-9]

        def worst_load(t):
            """The sample of largest petiole force (any leaf) while target
            ``t`` was handled, or None."""
            d = during(t)
            return max(d, key=lambda s: s.petiole_force) if d else None

        def worst_strain(t):
            """The largest blade strain percentile (any leaf) while target
            ``t`` was handled, or None."""
            d = during(t)
            return float(max(s.strain_percentile for s in d)) if d else None
        from lmap_drake.perception.points import Intrinsics
        from lmap_drake.plants.outcome import TruthFruitOfInstance
        K = Intrinsics.FromCameraConfig(self.scenario.cameras["camera0"])

        def truth_of(t):
            """(true fruit, fraction of the target's points on a fruit): from
            the render labels of the view it was planned in; a phantom
            (points mostly not on a fruit) is (None, fraction); without
            those, the fruit nearest the target's estimated centre."""
            est, k = t.get("initial_estimate"), t.get("view_plan")
            if est is not None and k is not None and 0 <= k < len(label) \
                    and label[k] is not None:
                found = TruthFruitOfInstance(est.semantic, t["target"].get("fruit_id"),
                                             label[k], K)
                if found is not None:
                    return found
            c = np.asarray(t["target"]["center_W"], float)
            return int(np.argmin([np.linalg.norm(f.center_W - c) for f in model.fruits])), None

        def dropped(est):
            from lmap_drake.shape.completion import DroppedFragments
            sem = getattr(est, "semantic", None)
            return None if sem is None else DroppedFragments(sem.flags)

        def executed(u):
            """The candidates target ``u`` executed (its plan, then its
            continuations), in order."""
            plans = ([u["plan"]] if u["plan"] is not None else []) + u["continuations"]
            return [p.chosen for p in plans if p.chosen is not None][:u["motions"]]
        targets = {}
        rows = []           # every target in turn, also a second one on the same fruit
        for t in st.targets:
            if t.get("target"):
                i, on_fruit = truth_of(t)
                if i is not None:
                    targets.setdefault(i, []).append(t)
                worst = worst_load(t)
                rows.append({"fruit": i, "phantom": i is None,
                             "points_on_fruit": None if on_fruit is None else round(on_fruit, 3),
                             "fruit_id": t["target"].get("fruit_id"),
                             "center_W": t["target"]["center_W"],
                             "leaf_id": t["target"].get("leaf_id"), "outcome": t["outcome"],
                             "motions": [c.action.Describe() for c in executed(t)],
                             "t_start": t["t_start"], "t_end": t["t_end"],
                             "max_petiole_force": (None if worst is None
                                                   else float(worst.petiole_force)),
                             "max_strain_percentile": worst_strain(t),
                             # fruit fragments dropped as no fruit (CompletePlant)
                             # in the view it was planned in and in its re-estimate
                             "fragments_dropped": [dropped(t.get(k)) for k in
                                                   ("initial_estimate", "final_estimate")]})
        record["targets"] = rows
        record["phantom_targets"] = sum(r["phantom"] for r in rows)
        fruits = []
        for i, f in enumerate(model.fruits):
            ts = targets.get(i, [])
            t = ts[0] if ts else None
            v0 = vis(i, 0)
            entry = {"fruit": i, "occlusion_requested": f.occlusion_requested,
                     "occluders": list(f.occluders),
                     "one_leaf_ceiling": float(getattr(f, "one_leaf_ceiling", 1.0)),
                     "visibility_initial": v0, "visibility_final": v0,
                     "targeted": t is not None, "shape_initial": None, "shape_final": None,
                     "action": None, "motions": [], "leaf_id": None, "why": "",
                     "outcome": "not planned for (predicted visible, or not seen)",
                     "reveals": []}
            if t is not None:
                # a fruit under two leaves may be revealed twice, each time
                # by another leaf: its final visibility is the best view a
                # reveal gave, its final shape the last re-estimate's
                ini = t["initial_estimate"].fruit if t["initial_estimate"] else None
                last = next((u for u in ts[::-1] if u["final_estimate"] is not None
                             and u["motions"]), t)
                fin = last["final_estimate"].fruit if last["final_estimate"] else None
                after = [vis(i, u["view_after"]) for u in ts if u["view_after"] is not None]
                entry.update(
                    visibility_initial=vis(i, t["view_plan"]),
                    visibility_final=max(after) if after else vis(i, t["view_plan"]),
                    shape_initial=FruitShapeErrors(ini, f.mesh_W, f.peduncle_axis_W),
                    shape_final=FruitShapeErrors(fin or ini, f.mesh_W, f.peduncle_axis_W),
                    action=(t["plan"].chosen.Row() if t["plan"] is not None
                            and t["plan"].chosen is not None else None),
                    motions=[c.Row() for u in ts for c in executed(u)],
                    leaf_id=t["target"].get("leaf_id"), why=t["target"].get("why", ""),
                    outcome=t["outcome"],
                    reveals=[{"leaf_id": u["target"].get("leaf_id"),
                              "why": u["target"].get("why", ""), "outcome": u["outcome"],
                              "motions": u["motions"],
                              "visibility_after": (None if u["view_after"] is None
                                                   else vis(i, u["view_after"]))}
                             for u in ts])
                # the petiole load while this fruit was handled (any leaf), N
                loads = [(worst_load(u), u) for u in ts]
                loads = [(w, u) for w, u in loads if w is not None]
                if loads:
                    worst, _ = max(loads, key=lambda wu: wu[0].petiole_force)
                    entry.update(max_petiole_force=float(worst.petiole_force),
                                 max_petiole_force_t=float(worst.t),
                                 max_strain_percentile=max(worst_strain(u) for _, u in loads))
            # every captured view together: what the fused views saw of it
            # (a fruit under two leaves shows different parts as each is moved)
            shown = [x for x in label if x is not None]
            entry["visibility_union"] = sim.VisibilityUnion(shown, fruit=i) if shown else v0
            fruits.append(entry)
        record["fruits"] = fruits
        cfg = self.scenario.plant_scene.outcome
        v0 = [e["visibility_initial"] for e in fruits]
        v1 = [e["visibility_final"] for e in fruits]
        record["outcome"] = Summarize(sim.samples, cfg, float(np.mean(v0)),
                                      float(np.mean(v1))).to_dict()
        record["outcome"]["fruits_revealed"] = int(sum(v >= 0.9 for v in v1))
        # the fruits one leaf's move could show >= 0.9 (the rest need two leaves moved)
        record["outcome"]["fruits_one_leaf_reachable"] = int(
            sum(e["one_leaf_ceiling"] >= 0.9 for e in fruits))
        shapes = [(e["shape_initial"], e["shape_final"]) for e in fruits if e["shape_final"]]
        mean = (lambda rows: None if not rows else
                {k: float(np.mean([r[k] for r in rows])) for k in rows[0]})
        record["shape_initial"] = mean([a for a, _ in shapes if a])
        record["shape_final"] = mean([b for _, b in shapes])
        record["plant"] = {"fruits": len(model.fruits), "leaves": len(model.leaves)}
        record["simulated_seconds"] = sim.time


class HardwareWorld:
    """The real cell (or the project's fakes) behind ``RunEpisode``: the
    episode Diagram on ``MakeHardwareStation``, stepped against the wall
    clock at ``realtime_rate`` (0: as fast as it goes, for fakes)."""
    hardware = True

    def __init__(self, scenario: Scenario, resources: EpisodeResources, options, clients,
                 read_only: bool = False, realtime_rate: float = 1.0, progress=None):
        from lmap_drake.station.hardware.station import MakeHardwareStation
        self.scenario = scenario
        self.clients = clients
        self.station = MakeHardwareStation(scenario, clients, read_only=read_only)
        self.diagram = MakeEpisodeDiagram(scenario, resources, self.station, options)
        self.simulator = Simulator(self.diagram)
        self.simulator.set_target_realtime_rate(0.0)   # paced here, see Step
        self.context = self.simulator.get_mutable_context()
        self.rate = float(realtime_rate)
        self.progress = progress or (lambda m: None)
        self._closed = False
        self.simulator.Initialize()
        self.Pause()

    @property
    def time(self) -> float:
        return self.context.get_time()

    def Start(self) -> None:
        self.Pause()

    def Pause(self) -> None:
        """Restarts the wall-clock pacing (after planning or a prompt: the
        run does not race to catch up)."""
        self._t0, self._wall0 = self.time, time.monotonic()

    def Step(self, dt: float) -> None:
        target = self.time + dt
        self.simulator.AdvanceTo(target)
        if self.rate > 0:
            delay = self._wall0 + (target - self._t0) / self.rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -0.25:      # a long computation (planning): do not catch up
                self.Pause()

    def AfterStep(self, controller, cctx, st) -> str:
        return ""

    def CurrentImages(self) -> dict:
        ctx = self.station.GetMyContextFromRoot(self.context)
        out = {}
        for name in ("rgb_image", "depth_image", "label_image"):
            image = self.station.GetOutputPort(f"camera0.{name}").Eval(ctx)
            copy_ = type(image)(image.width(), image.height())
            copy_.mutable_data[:] = image.data
            out[name] = copy_
        return out

    def Score(self, record: dict, views, st) -> None:
        record["outcome"] = None      # no ground truth on the real cell

    def Close(self) -> None:
        """Stops the arm and closes every client (the gripper is not moved)."""
        if not self._closed:
            self._closed = True
            from lmap_drake.station.hardware.station import StopHardwareStation
            StopHardwareStation(self.station)


class LeafAnimator:
    """Meshcat's recording does not animate deformable bodies: this adds the
    leaf's surface as a triangle mesh every ``period`` simulated seconds and
    toggles the snapshots' visibility in the recording, so the saved HTML
    shows the leaf moving."""

    def __init__(self, meshcat, world, period: float = 0.2):
        from lmap_drake.plants.leaf import BoundaryTriangles
        self.meshcat, self.world, self.period = meshcat, world, period
        model = world.model
        tets = ([leaf.tets for leaf in model.leaves] if hasattr(model, "leaves")
                else [model.leaf_tets])       # every leaf of a multi plant
        self.faces = [np.asarray(BoundaryTriangles(t), np.int32).T.copy() for t in tets]
        self.k, self.next_time, self.previous = 0, 0.0, None

    def __call__(self) -> None:
        from pydrake.geometry import Rgba
        t = self.world.time
        if self.meshcat is None or t < self.next_time:
            return
        path = f"/leaf_snapshots/{self.k:04d}"
        for j, faces in enumerate(self.faces):
            V = np.asarray(self.world.LeafVertices(j).T, float, order="F")
            self.meshcat.SetTriangleMesh(f"{path}/leaf_{j}", V, np.asfortranarray(faces),
                                         Rgba(0.2, 0.6, 0.15, 1.0))
        self.meshcat.SetProperty(path, "visible", False, 0.0)
        self.meshcat.SetProperty(path, "visible", True, t)
        if self.previous is not None:
            self.meshcat.SetProperty(self.previous, "visible", False, t)
        self.previous, self.k, self.next_time = path, self.k + 1, t + self.period


# ------------------------------------------------------------------ runner
@dc.dataclass
class EpisodeResult:
    """What ``RunEpisode`` returns (``SaveEpisode`` writes it)."""
    record: dict
    world: object
    images_before: dict | None
    images_after: dict | None
    status: object
    views: tuple = ()


def ControllerOptionsFor(scenario: Scenario, hardware: bool, plan_only: bool = False,
                         confirm: bool = False, initial_q=None, initial_gripper=None):
    """The ArmController's options on the simulated or the hardware station."""
    from lmap_drake.systems.arm_controller import ControllerOptions
    opts = ControllerOptions(initial_q=initial_q, initial_gripper=initial_gripper,
                             grasp_ack_required=not hardware, plan_only=plan_only,
                             confirm=confirm, release=scenario.planner.release_and_retreat)
    if hardware:
        from lmap_drake.station.hardware.safety import SafetyChecker
        checker = SafetyChecker(scenario.hardware.ur)
        opts.max_joint_speed = scenario.hardware.ur.joint_speed_limit
        opts.trajectory_check = checker.CheckTrajectory
    return opts


def DescribePlan(plan) -> str:
    """The chosen action, its predicted energy and visibility, in one line."""
    c = plan.chosen
    a = c.action
    if c.approach is None:        # a continuation: the leaf is already held
        where = f"holding the leaf at {np.round(a.p_WG, 3).tolist()} m, "
    else:
        where = f"grasp {a.grasp_id} at {np.round(a.p_WG, 3).tolist()} m, "
    vis = (f"{c.seen / plan.seen_max:.2f} (from {plan.seen_init / plan.seen_max:.2f})"
           if plan.seen_max and c.seen >= 0 else "n/a")
    e = c.EnergyPerNode()
    how = (f"pull {a.distance * 100:.0f} cm along "
           f"{np.round(a.dp_W / max(a.distance, 1e-9), 2).tolist()}" if a.family == "pull" else
           f"{a.Describe()} about {np.round(a.axis_W, 2).tolist()} through the estimated "
           f"petiole attachment {np.round(a.pivot_W, 3).tolist()} m")
    return (f"{where}{how}"
            f"; predicted visibility {vis}; predicted energy per node "
            + (f"{e:.2e} m^2" if e is not None else "n/a"))


def RunEpisode(scenario: Scenario, world, progress: Callable[[str], None] | None = None,
               max_time: float = 60.0, confirm: Callable | None = None) -> EpisodeResult:
    """Steps ``world`` (``SimWorld`` or ``HardwareWorld``) until its
    controller is finished (or ``max_time`` station seconds). ``confirm(plan)
    -> (accepted, note)`` answers the controller's ``confirm_wait``. A
    ``HardwareAbort`` or any exception inside the Diagram ends the episode
    with status ``aborted`` and a message (the world stops its arm)."""
    from lmap_drake.station.camera_noise import CameraProfile

    progress = progress or (lambda m: None)
    wall0 = time.perf_counter()

    def controller():
        c = world.diagram.GetSubsystemByName("arm_controller")
        return c, c.GetMyContextFromRoot(world.context)
    step_wall = 0.0
    mode_wall: dict[str, float] = {}     # wall seconds of the steps begun in each mode
    mode = "idle"
    error = ""
    dt = 0.05
    try:
        world.Start()
        while world.time < max_time:
            t0 = time.perf_counter()
            world.Step(dt)
            took = time.perf_counter() - t0
            step_wall += took
            mode_wall[mode] = mode_wall.get(mode, 0.0) + took
            c, cctx = controller()
            st = c.Status(cctx)
            mode = st.mode
            if st.finished:
                break
            # While the pads close, the grasp is made at the first 10 ms tick
            # at which they reach the attach opening: a 50 ms tick let a
            # squeeze push the thin leaf out first in one run of a scene and
            # not in another.
            dt = 0.01 if st.mode == "close_gripper" else 0.05
            if st.mode == "confirm_wait" and st.confirmed is None:
                asked = st.pending_motion[0] if st.pending_motion is not None else st.plan
                accepted, note = confirm(asked) if confirm is not None else (
                    False, "no operator to confirm")
                c.Confirm(cctx, accepted, note)
                world.Pause()
                continue
            if st.mode == "plan_requested" or st.mode == "observe":
                world.Pause()
            message = world.AfterStep(c, cctx, st)
            if message:
                error = message
                progress(f"aborted: {message}")
                break
    except KeyboardInterrupt:
        raise
    except Exception as err:  # noqa: BLE001 - a HardwareAbort, or a failure in the Diagram
        from lmap_drake.station.hardware.safety import HardwareAbort
        kind = "hardware" if isinstance(err, HardwareAbort) else "stage_error: diagram"
        error = (f"{kind} at t = {world.time:.2f} s: "
                 + (str(err) if isinstance(err, HardwareAbort) else
                    f"{type(err).__name__}: {' '.join(str(err).split())}"))
        progress(f"aborted: {error}")
    c, cctx = controller()
    st = c.Status(cctx)
    views = tuple(world.diagram.GetSubsystemByName("view_recorder").GetOutputPort(
        "views").Eval(world.diagram.GetSubsystemByName("view_recorder").GetMyContextFromRoot(
            world.context)))
    from lmap_drake.systems.view_recorder import ViewImages

    def images(view):
        rgb, depth, label = ViewImages(view)
        return {"rgb_image": rgb, "depth_image": depth, "label_image": label}
    current = world.CurrentImages()
    before = images(views[0]) if views else current
    after = images(views[-1]) if len(views) >= 2 else current
    plan = st.plan
    chosen = plan.chosen.Row() if plan is not None and plan.chosen is not None else None
    record = {
        "scenario": scenario.plant_scene.name or "default",
        "station": "hardware" if world.hardware else "simulation",
        "method": scenario.planner.method,
        "energy_weight": scenario.planner.energy_weight,
        "perception": {"segmenter": scenario.perception.segmenter,
                       "camera": "device" if world.hardware else CameraProfile(
                           scenario.camera_noise)},
        "status": "aborted" if error else st.mode,
        "message": error or st.message,
        # ok | no_action_needed | no_fruit | no_feasible_action | stage_error
        "plan_status": "stage_error" if error.startswith("stage_error") else (
            plan.status if plan is not None else ("stage_error" if st.failed_stage else None)),
        "failed_stage": "diagram" if error.startswith("stage_error") else (
            st.failed_stage or None),
        "chosen_action": chosen,
        # Every executed motion: the plan's action, then the continuations
        # planned from the held leaf (``planner.max_replans``).
        "motions": [dict(p.chosen.Row(), predicted_visibility=(
            p.chosen.seen / p.seen_max if p.seen_max and p.chosen.seen >= 0 else None))
            for p in st.plans if p.chosen is not None][:len(st.motion_paths)],
        "replans": list(st.replan_log),
        # The planner's own visibility model (voxels of the estimated fruit):
        # seen initially, at most (fruit alone) and after the chosen action.
        "predicted_visibility": None if plan is None or not plan.seen_max else {
            "initial": plan.seen_init / plan.seen_max,
            "chosen": (plan.chosen.seen / plan.seen_max
                       if plan.chosen is not None and plan.chosen.seen >= 0 else None)},
        "outcome": None,
        "shape_initial": None,
        "shape_final": None,
        "stage_seconds": st.stage_seconds,
        "simulated_seconds": world.time,
        "simulation_wall_seconds": step_wall,
        "mode_wall_seconds": {k: round(v, 2) for k, v in mode_wall.items()},
        "wall_seconds": None,
        "mode_log": st.mode_log,
    }
    world.Score(record, views, st)
    record["wall_seconds"] = time.perf_counter() - wall0
    return EpisodeResult(record, world, before, after, st, views)


# Station seconds an episode may take per fruit of the plant (an episode
# with one reveal takes 15-30 s; a fruit under two leaves revealed by each
# about twice that).
SECONDS_PER_FRUIT = 60.0
# Fruits assumed on hardware with ``planner.targets: all``, where the plant's
# fruit count is not known before the first view.
HARDWARE_MAX_FRUITS = 4


def EpisodeTimeLimit(scenario: Scenario, per_fruit: float = SECONDS_PER_FRUIT) -> float:
    """Station seconds after which ``RunEpisode`` stops waiting for the
    controller: ``per_fruit`` times the simulated plant's fruit count
    (``plant_scene.multi.fruits``; 1 for a one-fruit plant), or times
    ``HARDWARE_MAX_FRUITS`` on a plant of unknown fruit count handled
    fruit by fruit (``planner.targets: all`` and no simulated multi-fruit
    plant)."""
    if scenario.plant_scene.kind == "multi":
        return per_fruit * max(1, len(scenario.plant_scene.multi.fruits))
    if scenario.planner.targets == "all":
        return per_fruit * HARDWARE_MAX_FRUITS
    return per_fruit


def RunSimEpisode(scenario: Scenario, meshcat=None,
                  progress: Callable[[str], None] | None = None,
                  max_time: float = SECONDS_PER_FRUIT,
                  resources: EpisodeResources | None = None, plan_only: bool = False
                  ) -> EpisodeResult:
    """One full episode on the simulated plant world (no confirmation),
    given ``max_time`` station seconds per fruit (``EpisodeTimeLimit``)."""
    progress = progress or (lambda m: None)
    max_time = EpisodeTimeLimit(scenario, max_time)
    resources = resources or EpisodeResources.Make(scenario, progress)
    resources.progress = progress
    world = SimWorld(scenario, resources, ControllerOptionsFor(scenario, False, plan_only),
                     meshcat, progress)
    return RunEpisode(scenario, world, progress, max_time)


# ------------------------------------------------------------------ outputs
def PlanRecord(plan, stage_seconds: dict | None = None) -> dict:
    """``plan.json``: the planner's answer (status, chosen action, predicted
    visibility, stage timings), the same for a run and its replay."""
    if plan is None:
        return {"status": None}
    out = {"status": plan.status, "method": plan.method, "message": plan.message,
           "chosen_action": plan.chosen.Row() if plan.chosen is not None else None,
           "predicted_visibility": None if not plan.seen_max else {
               "initial": plan.seen_init / plan.seen_max,
               "chosen": (plan.chosen.seen / plan.seen_max
                          if plan.chosen is not None and plan.chosen.seen >= 0 else None)},
           "num_candidates": len(plan.candidates),
           "num_feasible": sum(c.feasible for c in plan.candidates)}
    if stage_seconds is not None:
        out["stage_seconds"] = stage_seconds
    return out


def RecordingCamera(scenario: Scenario, clients=None) -> tuple[dict, np.ndarray]:
    """(camera dict, X_WC 4x4) of camera0 as the episode used it."""
    from lmap_drake.perception.points import Intrinsics
    cam = scenario.cameras["camera0"]
    K = Intrinsics.FromCameraConfig(cam)
    info = {"width": K.width, "height": K.height, "fx": K.fx, "fy": K.fy, "cx": K.cx,
            "cy": K.cy}
    if clients is not None:
        info["serial"] = str(getattr(clients.camera, "serial", ""))
        info["depth_scale"] = float(getattr(clients.camera, "depth_scale", float("nan")))
    return info, cam.X_PB.GetDeterministicValue().GetAsMatrix4()


def SaveEpisode(result: EpisodeResult, out: Path, clients=None) -> list[str]:
    """Writes ``episode.json``, ``plan.json``, ``candidates.json``, the
    recording, RGB/depth of view 0 (and label in simulation), view 1, the
    images with the segmentation overlaid, the plan over the camera image
    and the shape pictures."""
    from lmap_drake.evaluation.figures import SaveEpisodeFigures
    from lmap_drake.perception.recording import SaveRecording
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    world = result.world
    (out / "episode.json").write_text(json.dumps(result.record, indent=2, default=float))
    files = ["episode.json"]
    plan = result.status.plan
    (out / "plan.json").write_text(json.dumps(PlanRecord(plan, result.status.stage_seconds),
                                              indent=1, default=float))
    files.append("plan.json")
    if plan is not None:
        plan.SaveJson(out / "candidates.json")
        files.append("candidates.json")
    # every re-plan from the held leaf, executed or not (its status says)
    for k, cont in enumerate(result.status.replan_results, start=1):
        cont.SaveJson(out / f"continuation_{k}.json")
        files.append(f"continuation_{k}.json")
    camera, X_WC = RecordingCamera(world.scenario, clients)
    files += SaveRecording(out, result.views, camera, X_WC,
                           "hardware" if world.hardware else "simulation")
    if result.images_before is not None:
        SaveRgb(result.images_before["rgb_image"], out / "rgb.png")
        SaveDepth(result.images_before["depth_image"], out / "depth.png")
        files += ["rgb.png", "depth.png"]
        if not world.hardware:
            SaveLabel(result.images_before["label_image"], out / "label.png")
            files.append("label.png")
    if len(result.views) >= 2 and result.images_after is not None:
        SaveRgb(result.images_after["rgb_image"], out / "rgb_after.png")
        files.append("rgb_after.png")
        if not world.hardware:
            SaveLabel(result.images_after["label_image"], out / "label_after.png")
            files.append("label_after.png")
    files += SaveEpisodeFigures(result, out)
    if result.record.get("outcome") is not None:
        (out / "outcome.json").write_text(json.dumps(result.record["outcome"], indent=2))
        files.append("outcome.json")
    return files


def ConsoleConfirm(plan) -> tuple[bool, str]:
    """Shows the chosen action and asks the operator to type ``yes``."""
    print(f"[lmap-drake] chosen action: {DescribePlan(plan)}", flush=True)
    try:
        answer = input("[lmap-drake] move the robot to execute it? type 'yes' to move: ")
    except EOFError:
        return False, "no answer (end of input)"
    answer = answer.strip().lower()
    return (answer == "yes"), (f"answered {answer!r}" if answer != "yes" else "")


def RunLmapEpisode(scenario: Scenario, out: Path, progress: Callable[[str], None] = print,
                   hardware: bool = False, plan_only: bool = False, confirm: bool = False,
                   confirm_fn: Callable | None = None, clients=None,
                   realtime_rate: float | None = None,
                   resources: EpisodeResources | None = None
                   ) -> tuple[list[str], str]:
    """The full LMAP loop on the simulated station (the FEM plant world) or
    the hardware station (``clients`` injected, e.g. the project's fakes, or
    connected here), paced at ``realtime_rate`` station seconds per wall
    second (None: 1, or the digital twin's pace). Writes ``scenario.yaml`` (as run:
    on hardware with the device's intrinsics and the calibrated pose),
    ``episode.json``, ``plan.json``, ``candidates.json``, ``recording/``, images,
    figures, ``diagram.svg``, and in simulation the ground truth, ``outcome.json``
    and ``scene.html``. Returns (files, status: done | planned | aborted ...).
    """
    from lmap_drake.diagram import WriteDiagramSvg

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    confirm_fn = confirm_fn or ConsoleConfirm
    meshcat = None
    own = False
    if hardware:
        from lmap_drake.station.hardware.run import PrepareHardware
        scenario, clients, own = PrepareHardware(scenario, clients, read_only=plan_only,
                                                 progress=progress)
    files = ["scenario.yaml"]
    world = None
    try:
        DumpScenario(scenario, out / "scenario.yaml")
        progress("loading the shape template, building the diagram")
        resources = resources or EpisodeResources.Make(scenario, progress)
        resources.progress = progress
        if hardware:
            q0, _ = clients.ur.ReadState()
            opts = ControllerOptionsFor(scenario, True, plan_only, confirm, initial_q=q0,
                                        initial_gripper=clients.gripper.Opening())
            if realtime_rate is None:    # a digital twin's camera tells its pace
                realtime_rate = float(getattr(clients.camera, "time_scale", 1.0))
                if realtime_rate != 1.0:
                    progress(f"running at {realtime_rate:g} station seconds per wall second "
                             f"(the twin's pace)")
            world = HardwareWorld(scenario, resources, opts, clients, read_only=plan_only,
                                  realtime_rate=realtime_rate, progress=progress)
        else:
            meshcat = Meshcat()
            opts = ControllerOptionsFor(scenario, False, plan_only, confirm)
            world = SimWorld(scenario, resources, opts, meshcat, progress)
            if getattr(world.model, "occlusion_clamped", False):
                m = world.model
                progress(f"warning: the leaf hides at most {m.occlusion_predicted:.2f} of the "
                         f"fruit, not the requested plant_scene.occlusion "
                         f"{m.occlusion_requested:.2f} (clamped; recorded in episode.json)")
            FrameMeshcat(meshcat, scenario)
            meshcat.StartRecording()
        # A plant with several fruits gets its time per fruit, as in `eval`
        # (a fixed 60 s cut a two-fruit `run` short while it was releasing
        # a leaf).
        result = RunEpisode(scenario, world, progress, EpisodeTimeLimit(scenario),
                            confirm=confirm_fn)
    finally:
        if world is not None:
            world.Close()
        elif hardware and own:
            clients.Close()
    if meshcat is not None:
        meshcat.StopRecording()
        meshcat.PublishRecording()
    files += SaveEpisode(result, out, clients if hardware else None)
    if not hardware and hasattr(world.model, "leaves"):
        from lmap_drake.plants.multi import SaveMultiGroundTruth
        files += SaveMultiGroundTruth(world.model, out)
    elif not hardware:
        from lmap_drake.plants.generator import SaveGroundTruth
        files += SaveGroundTruth(world.model, out)
    files.append("diagram.svg" if WriteDiagramSvg(world.diagram, out / "diagram.svg")
                 else "diagram.dot")
    if meshcat is not None:
        (out / "scene.html").write_text(meshcat.StaticHtml())
        files.append("scene.html")
    r = result.record
    progress(f"episode {r['status']}: {r['message'] or '(no message)'}")
    if r["outcome"] is not None:
        progress(OutcomeLine(r["outcome"]))
    if r["shape_initial"] and r["shape_final"]:
        progress(f"Chamfer {r['shape_initial']['chamfer_cm']:.2f} cm -> "
                 f"{r['shape_final']['chamfer_cm']:.2f} cm; wall {r['wall_seconds']:.0f} s")
    return files, str(r["status"])


def OutcomeLine(outcome: dict) -> str:
    """The outcome as one line for the terminal (floats to 3 decimals; the
    full values are in ``outcome.json`` / ``episode.json``)."""
    return "outcome: " + ", ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}"
                                   for k, v in outcome.items())


# ------------------------------------------------------------------ replay
def ReplayRun(run_dir: Path, out: Path, scenario_text: str = "{}",
              progress: Callable[[str], None] = print) -> tuple[list[str], dict]:
    """Re-runs perception, shape completion and planning on the view a run
    recorded (``run_dir/recording``), with the run's ``scenario.yaml`` and
    ``scenario_text`` overrides. Writes ``scenario.yaml``, ``plan.json``,
    ``candidates.json``, ``replay.json`` (the run's and the replay's chosen
    action, same or not, timings), ``rgb_before_segmented.png`` and
    ``plan_on_image.png``. Returns (files, replay record)."""
    from lmap_drake.diagram import MakeReplayDiagram
    from lmap_drake.perception.recording import LoadRecording, RecordingError
    from lmap_drake.scenario import LoadScenario, ScenarioWithCamera
    from lmap_drake.systems.view_recorder import RecordedViews

    run_dir, out = Path(run_dir), Path(out)
    recording = LoadRecording(run_dir)
    out.mkdir(parents=True, exist_ok=True)
    scenario_file = run_dir / "scenario.yaml"
    if not scenario_file.exists():
        raise RecordingError(f"{scenario_file} not found: a replay needs the run's scenario")
    scenario = LoadScenario(filename=str(scenario_file), scenario_text=scenario_text, bare=True)
    scenario = ScenarioWithCamera(scenario, recording.camera, recording.X_WC)
    if recording.station == "hardware":
        scenario.perception.no_return_free_range = 0.0
    if scenario.perception.segmenter == "label" and recording.views[0].label is None:
        raise RecordingError(f"{run_dir}: the recording has no label images (a hardware "
                             f"run); the label segmenter cannot replay it")
    DumpScenario(scenario, out / "scenario.yaml")
    progress(f"replaying view 0 of {recording.folder} ({recording.station} run)")
    t0 = time.perf_counter()
    resources = EpisodeResources.Make(scenario, progress)
    t_load = time.perf_counter() - t0
    diagram = MakeReplayDiagram(scenario, resources, RecordedViews(recording.views, 1))
    ctx = diagram.CreateDefaultContext()

    def timed(name):
        system = diagram.GetSubsystemByName(name)
        port = {"perception": "semantic_scene", "shape_completion": "scene_estimate",
                "action_selection": "plan"}[name]
        t = time.perf_counter()
        value = system.GetOutputPort(port).Eval(system.GetMyContextFromRoot(ctx))
        return value, time.perf_counter() - t
    semantic, seg_s = timed("perception")
    estimate, ssc_s = timed("shape_completion")
    plan, plan_s = timed("action_selection")
    stage_seconds = {"segmentation_s": seg_s, "shape_completion_s": ssc_s,
                     "planning_s": plan_s, **plan.timings}
    files = ["scenario.yaml", "plan.json", "replay.json"]
    (out / "plan.json").write_text(json.dumps(PlanRecord(plan, stage_seconds), indent=1,
                                              default=float))
    plan.SaveJson(out / "candidates.json")
    files.append("candidates.json")
    original = None
    if (run_dir / "plan.json").exists():
        original = json.loads((run_dir / "plan.json").read_text()).get("chosen_action")
    mine = plan.chosen.Row() if plan.chosen is not None else None
    same = None if original is None and mine is None else (
        original is not None and mine is not None and all(
            original[k] == mine[k] for k in ("grasp_id", "direction_id", "distance")))
    record = {"run": str(run_dir), "scenario_text": scenario_text, "status": plan.status,
              "message": plan.message, "chosen_action": mine, "run_chosen_action": original,
              "same_action_as_run": same,
              "planning_wall_seconds": seg_s + ssc_s + plan_s,
              "template_load_seconds": t_load, "stage_seconds": stage_seconds}
    (out / "replay.json").write_text(json.dumps(record, indent=1, default=float))
    files += SavePlanFigures(scenario, recording.views[0], plan, estimate, out)
    progress(f"replay plan {plan.status}: " + (DescribePlan(plan) if plan.chosen is not None
                                               else plan.message))
    progress(f"planning on the replayed capture: {record['planning_wall_seconds']:.1f} s; "
             + ("same action as the run" if same else "a different action from the run"
                if same is False else "the run had no plan to compare"))
    return files, record


def SavePlanFigures(scenario: Scenario, view, plan, estimate, out: Path) -> list[str]:
    """``rgb_before_segmented.png`` and ``plan_on_image.png`` for one view."""
    from lmap_drake.evaluation.figures import Overlay, PlanOnImage
    from lmap_drake.perception.points import Intrinsics
    from lmap_drake.perception.segmentation import MakeSegmenter
    from lmap_drake.viz import SavePng
    cam = scenario.cameras["camera0"]
    K = Intrinsics.FromCameraConfig(cam)
    segmenter = MakeSegmenter(scenario.perception, K)
    seg = segmenter.Segment(view.rgb, view.depth[..., None], None if view.label is None
                            else view.label[..., None])
    SavePng(Overlay(view.rgb, seg.class_map, title=f"segmenter: {segmenter.name} (before)"),
            out / "rgb_before_segmented.png")
    SavePng(PlanOnImage(view.rgb, plan, estimate, K,
                        cam.X_PB.GetDeterministicValue().GetAsMatrix4()),
            out / "plan_on_image.png")
    return ["rgb_before_segmented.png", "plan_on_image.png"]
