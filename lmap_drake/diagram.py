"""The complete LMAP Diagram, built from one scenario:

    station -> Perception -> ShapeCompletion -> ActionCandidates
            -> DeformationPrediction -> ActionSelection -> ArmController -> station
    Perception (fused views) -> ShapeCompletion (re-estimation) -> ArmController

Heavy, reusable objects (the DeepSDF decoder, the planner's robot model) live
in ``EpisodeResources`` and are shared across rebuilds (the simulated grasp
rebuilds the Diagram, see ``lmap_drake.plants.simworld``).
"""
from __future__ import annotations

import dataclasses as dc

from pydrake.systems.framework import Diagram, DiagramBuilder

from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.scenario import Scenario
from lmap_drake.station.station import MakeStation


@dc.dataclass
class EpisodeResources:
    """Objects built once per episode and shared by every rebuild."""
    robot: RobotModel
    decoder: object = None
    mean_latent: object = None
    progress: object = None

    @staticmethod
    def Make(scenario: Scenario, progress=None) -> "EpisodeResources":
        from lmap_drake.shape.deepsdf import LoadDecoder
        decoder, mean_latent, _ = LoadDecoder(scenario.shape.weights_file)
        return EpisodeResources(RobotModel(scenario.robot.X_WB.GetDeterministicValue()),
                                decoder, mean_latent, progress)


def MakeEpisodeDiagram(scenario: Scenario, resources: EpisodeResources, meshcat=None,
                       leaf_grasp=None, hardware: bool = False) -> tuple[Diagram, Diagram]:
    """Returns (root Diagram, station). Systems are named after the paper's
    stages; the station is ``station``."""
    from lmap_drake.systems.arm_controller import ArmController
    from lmap_drake.systems.deformation import DeformationPrediction
    from lmap_drake.systems.perception import Perception
    from lmap_drake.systems.planning import ActionCandidates, ActionSelection
    from lmap_drake.systems.shape_completion import ShapeCompletion

    b = DiagramBuilder()
    station = b.AddNamedSystem(
        "station", MakeStation(scenario, meshcat, hardware=hardware, leaf_grasp=leaf_grasp))
    cam = scenario.cameras["camera0"]
    perception = b.AddNamedSystem("perception", Perception(cam, scenario.perception))
    for name in ("rgb_image", "depth_image", "label_image"):
        b.Connect(station.GetOutputPort(f"camera0.{name}"),
                  perception.GetInputPort(f"camera0.{name}"))
    shape = b.AddNamedSystem("shape_completion", ShapeCompletion(
        scenario.shape, resources.decoder, resources.mean_latent))
    reest = b.AddNamedSystem("shape_reestimation", ShapeCompletion(
        scenario.shape, resources.decoder, resources.mean_latent, reestimate=True))
    b.Connect(perception.GetOutputPort("semantic_scene"), shape.GetInputPort("semantic_scene"))
    b.Connect(perception.GetOutputPort("fused_semantic_scene"),
              reest.GetInputPort("semantic_scene"))
    candidates = b.AddNamedSystem("action_candidates",
                                  ActionCandidates(scenario, resources.robot))
    deformation = b.AddNamedSystem("deformation_prediction",
                                   DeformationPrediction(scenario.deformation))
    selection = b.AddNamedSystem("action_selection", ActionSelection(scenario, candidates))
    b.Connect(shape.GetOutputPort("scene_estimate"), candidates.GetInputPort("scene_estimate"))
    b.Connect(station.GetOutputPort("ur5.position_measured"),
              candidates.GetInputPort("ur5.position"))
    b.Connect(station.GetOutputPort("ur5.position_measured"),
              selection.GetInputPort("ur5.position"))
    b.Connect(candidates.GetOutputPort("scene_estimate"),
              deformation.GetInputPort("scene_estimate"))
    b.Connect(candidates.GetOutputPort("actions"), deformation.GetInputPort("actions"))
    b.Connect(candidates.GetOutputPort("candidate_set"), selection.GetInputPort("candidate_set"))
    b.Connect(deformation.GetOutputPort("predictions"), selection.GetInputPort("predictions"))
    controller = b.AddNamedSystem("arm_controller", ArmController(
        scenario, resources.robot, grasp_ack_required=not hardware,
        progress=resources.progress))
    b.Connect(selection.GetOutputPort("plan"), controller.GetInputPort("plan"))
    b.Connect(perception.GetOutputPort("semantic_scene"), controller.GetInputPort("semantic_scene"))
    b.Connect(shape.GetOutputPort("scene_estimate"), controller.GetInputPort("scene_estimate"))
    b.Connect(reest.GetOutputPort("scene_estimate"), controller.GetInputPort("final_estimate"))
    b.Connect(station.GetOutputPort("ur5.state_estimated"),
              controller.GetInputPort("ur5.state_estimated"))
    b.Connect(station.GetOutputPort("gripper.state_measured"),
              controller.GetInputPort("gripper.state_measured"))
    b.Connect(controller.GetOutputPort("ur5.position"), station.GetInputPort("ur5.position"))
    b.Connect(controller.GetOutputPort("gripper.position"),
              station.GetInputPort("gripper.position"))
    b.Connect(controller.GetOutputPort("capture"), perception.GetInputPort("capture"))
    diagram = b.Build()
    diagram.set_name("lmap")
    return diagram, station


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
