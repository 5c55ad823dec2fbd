"""The complete LMAP Diagram around a station (simulated or hardware):

    station -> ViewRecorder -> Perception -> ShapeCompletion -> ActionCandidates
            -> DeformationPrediction -> ActionSelection -> ArmController -> station
    Perception (fused views) -> ShapeCompletion (re-estimation) -> ArmController
    ArmController (status) + re-estimation -> ContinuationPlanning -> ArmController

and the same planning stages on recorded views (``MakeReplayDiagram``).

Heavy, reusable objects (the DeepSDF decoder, the planner's robot model) live
in ``EpisodeResources`` and are shared across rebuilds (the simulated grasp
rebuilds the Diagram, see ``lmap_drake.plants.plant_sim``).
"""
from __future__ import annotations

import dataclasses as dc

from pydrake.systems.framework import Diagram, DiagramBuilder

from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.scenario import Scenario


@dc.dataclass
class EpisodeResources:
    """Objects built once per episode and shared by every rebuild."""
    robot: RobotModel
    decoder: object = None
    mean_latent: object = None
    progress: object = None
    fit_memo: object = None          # shape.completion.FitMemo: fruit fits of the episode

    @staticmethod
    def Make(scenario: Scenario, progress=None) -> "EpisodeResources":
        from lmap_drake.shape.deepsdf import LoadDecoder
        decoder, mean_latent, _ = LoadDecoder(scenario.shape.weights_file)
        from lmap_drake.shape.completion import FitMemo
        return EpisodeResources(RobotModel(scenario.robot.X_WB.GetDeterministicValue()),
                                decoder, mean_latent, progress,
                                FitMemo(tolerance=scenario.shape.reuse_tolerance))


def AddPlanningStages(b: DiagramBuilder, scenario: Scenario, resources: EpisodeResources,
                      views) -> dict:
    """Adds Perception -> ShapeCompletion -> ActionCandidates ->
    DeformationPrediction -> ActionSelection (and the re-estimation on the
    fused views) fed by ``views`` (a ``ViewRecorder`` or ``RecordedViews``:
    images and joints of the captured views). Returns the systems by name."""
    from lmap_drake.systems.deformation import DeformationPrediction
    from lmap_drake.systems.perception import Perception
    from lmap_drake.systems.planning import ActionCandidates, ActionSelection
    from lmap_drake.systems.shape_completion import ShapeCompletion

    cam = scenario.cameras["camera0"]
    perception = b.AddNamedSystem("perception", Perception(cam, scenario.perception,
                                                           robot=resources.robot))
    for name in ("rgb_image", "depth_image", "label_image"):
        b.Connect(views.GetOutputPort(name), perception.GetInputPort(f"camera0.{name}"))
    b.Connect(views.GetOutputPort("num_views"), perception.GetInputPort("capture"))
    b.Connect(views.GetOutputPort("ur5.position"), perception.GetInputPort("ur5.position"))
    b.Connect(views.GetOutputPort("gripper.opening"), perception.GetInputPort("gripper.opening"))
    shape = b.AddNamedSystem("shape_completion", ShapeCompletion(
        scenario.shape, resources.decoder, resources.mean_latent, fit_memo=resources.fit_memo))
    reest = b.AddNamedSystem("shape_reestimation", ShapeCompletion(
        scenario.shape, resources.decoder, resources.mean_latent, reestimate=True,
        focus_port=scenario.planner.targets == "all", fit_memo=resources.fit_memo))
    b.Connect(perception.GetOutputPort("semantic_scene"), shape.GetInputPort("semantic_scene"))
    b.Connect(perception.GetOutputPort("fused_semantic_scene"),
              reest.GetInputPort("semantic_scene"))
    candidates = b.AddNamedSystem("action_candidates",
                                  ActionCandidates(scenario, resources.robot))
    deformation = b.AddNamedSystem("deformation_prediction",
                                   DeformationPrediction(scenario.deformation))
    selection = b.AddNamedSystem("action_selection", ActionSelection(scenario, candidates))
    b.Connect(shape.GetOutputPort("scene_estimate"), candidates.GetInputPort("scene_estimate"))
    b.Connect(views.GetOutputPort("ur5.position"), candidates.GetInputPort("ur5.position"))
    b.Connect(views.GetOutputPort("ur5.position"), selection.GetInputPort("ur5.position"))
    b.Connect(candidates.GetOutputPort("scene_estimate"),
              deformation.GetInputPort("scene_estimate"))
    b.Connect(candidates.GetOutputPort("actions"), deformation.GetInputPort("actions"))
    b.Connect(candidates.GetOutputPort("candidate_set"), selection.GetInputPort("candidate_set"))
    b.Connect(deformation.GetOutputPort("predictions"), selection.GetInputPort("predictions"))
    return {"perception": perception, "shape_completion": shape, "shape_reestimation": reest,
            "action_candidates": candidates, "deformation_prediction": deformation,
            "action_selection": selection}


def MakeEpisodeDiagram(scenario: Scenario, resources: EpisodeResources, station: Diagram,
                       options=None) -> Diagram:
    """The whole episode around ``station`` (simulated or hardware: the same
    ports, ``lmap_drake.station.STATION_PORTS``): the station's camera and
    joints -> ViewRecorder -> the planning stages -> ArmController -> the
    station. ``options``: ``systems.arm_controller.ControllerOptions``.
    Systems are named after the paper's stages; the station is ``station``."""
    from lmap_drake.systems.arm_controller import ArmController
    from lmap_drake.systems.view_recorder import ViewRecorder

    b = DiagramBuilder()
    b.AddNamedSystem("station", station)
    views = b.AddNamedSystem("view_recorder", ViewRecorder())
    for name in ("rgb_image", "depth_image", "label_image"):
        b.Connect(station.GetOutputPort(f"camera0.{name}"),
                  views.GetInputPort(f"camera0.{name}"))
    b.Connect(station.GetOutputPort("ur5.state_estimated"),
              views.GetInputPort("ur5.state_estimated"))
    b.Connect(station.GetOutputPort("gripper.state_measured"),
              views.GetInputPort("gripper.state_measured"))
    stages = AddPlanningStages(b, scenario, resources, views)
    controller = b.AddNamedSystem("arm_controller", ArmController(
        scenario, resources.robot, options=options, progress=resources.progress))
    b.Connect(stages["perception"].GetOutputPort("semantic_scene"),
              controller.GetInputPort("semantic_scene"))
    if scenario.planner.targets == "all":
        # Several fruits: PlantPlanning plans the next fruit on the newest
        # view; TargetReestimate hands the current fruit's re-estimate on.
        from lmap_drake.systems.planning import PlantPlanning, TargetFocus, TargetReestimate
        plant = b.AddNamedSystem("plant_planning", PlantPlanning(scenario, resources.robot))
        b.Connect(stages["shape_completion"].GetOutputPort("plant_estimate"),
                  plant.GetInputPort("plant_estimate"))
        b.Connect(views.GetOutputPort("ur5.position"), plant.GetInputPort("ur5.position"))
        b.Connect(controller.GetOutputPort("status"), plant.GetInputPort("status"))
        b.Connect(plant.GetOutputPort("plan"), controller.GetInputPort("plan"))
        b.Connect(plant.GetOutputPort("scene_estimate"),
                  controller.GetInputPort("scene_estimate"))
        target = b.AddNamedSystem("target_reestimate", TargetReestimate(scenario,
                                                                         resources.robot))
        b.Connect(stages["shape_reestimation"].GetOutputPort("plant_estimate"),
                  target.GetInputPort("plant_estimate"))
        # the re-estimate completes only the fruit being revealed
        focus = b.AddNamedSystem("target_focus", TargetFocus())
        b.Connect(controller.GetOutputPort("status"), focus.GetInputPort("status"))
        b.Connect(focus.GetOutputPort("target_center"),
                  stages["shape_reestimation"].GetInputPort("target_center"))
        b.Connect(views.GetOutputPort("ur5.position"), target.GetInputPort("ur5.position"))
        b.Connect(controller.GetOutputPort("status"), target.GetInputPort("status"))
        reestimate = target.GetOutputPort("scene_estimate")
    else:
        b.Connect(stages["action_selection"].GetOutputPort("plan"),
                  controller.GetInputPort("plan"))
        b.Connect(stages["shape_completion"].GetOutputPort("scene_estimate"),
                  controller.GetInputPort("scene_estimate"))
        reestimate = stages["shape_reestimation"].GetOutputPort("scene_estimate")
    b.Connect(reestimate, controller.GetInputPort("final_estimate"))
    b.Connect(stages["perception"].GetOutputPort("num_views_fused"),
              controller.GetInputPort("views_fused"))
    b.Connect(station.GetOutputPort("ur5.state_estimated"),
              controller.GetInputPort("ur5.state_estimated"))
    b.Connect(station.GetOutputPort("gripper.state_measured"),
              controller.GetInputPort("gripper.state_measured"))
    if station.HasOutputPort("ur5.wrist_force"):
        b.Connect(station.GetOutputPort("ur5.wrist_force"),
                  controller.GetInputPort("ur5.wrist_force"))
    b.Connect(controller.GetOutputPort("ur5.position"), station.GetInputPort("ur5.position"))
    b.Connect(controller.GetOutputPort("gripper.position"),
              station.GetInputPort("gripper.position"))
    b.Connect(controller.GetOutputPort("capture"), views.GetInputPort("capture"))
    from lmap_drake.systems.planning import ContinuationPlanning
    replan = b.AddNamedSystem("continuation_planning", ContinuationPlanning(
        scenario, stages["action_candidates"]))
    b.Connect(controller.GetOutputPort("status"), replan.GetInputPort("status"))
    b.Connect(reestimate, replan.GetInputPort("scene_estimate"))
    b.Connect(views.GetOutputPort("ur5.position"), replan.GetInputPort("ur5.position"))
    b.Connect(replan.GetOutputPort("plan"), controller.GetInputPort("continuation"))
    diagram = b.Build()
    diagram.set_name("lmap")
    return diagram


def MakeReplayDiagram(scenario: Scenario, resources: EpisodeResources, views) -> Diagram:
    """The planning stages fed by recorded views (``RecordedViews``), no
    station and no controller: evaluate ``action_selection``'s ``plan``;
    with ``planner.targets: all`` also ``plant_planning`` (as in the
    episode), whose ``status`` input (the fruits handled so far, as the
    ``ArmController``'s status carries them) is exported as the Diagram's
    input ``status``."""
    b = DiagramBuilder()
    source = b.AddNamedSystem("recorded_views", views)
    stages = AddPlanningStages(b, scenario, resources, source)
    if scenario.planner.targets == "all":
        from lmap_drake.systems.planning import PlantPlanning
        plant = b.AddNamedSystem("plant_planning", PlantPlanning(scenario, resources.robot))
        b.Connect(stages["shape_completion"].GetOutputPort("plant_estimate"),
                  plant.GetInputPort("plant_estimate"))
        b.Connect(source.GetOutputPort("ur5.position"), plant.GetInputPort("ur5.position"))
        b.ExportInput(plant.GetInputPort("status"), "status")
    diagram = b.Build()
    diagram.set_name("lmap_replay")
    return diagram


def WriteDiagramSvg(diagram: Diagram, path) -> bool:
    """Writes the Diagram's graphviz as SVG (pydot); False if graphviz's
    ``dot`` is not installed (the .dot text is written instead)."""
    from pathlib import Path
    text = diagram.GetGraphvizString(max_depth=1)
    path = Path(path)
    try:
        import pydot
        graph = pydot.graph_from_dot_data(text)[0]
        graph.write_svg(str(path))
        return True
    except Exception:  # noqa: BLE001 -- dot binary missing
        path.with_suffix(".dot").write_text(text)
        return False
