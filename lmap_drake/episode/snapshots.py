"""The two runs of ``lmap-drake run`` without the planner: the station
snapshot (``RunStationSnapshot``: the arm held, camera0's images) and the
scripted pull of ``plant_scene.pull`` on the procedural plant world
(``RunScriptedPullEpisode``). World frame W, metres, seconds.
"""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable

from pydrake.geometry import Meshcat
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from lmap_drake.episode.records import OutcomeLine
from lmap_drake.episode.sim_world import FrameMeshcat
from lmap_drake.plants.generator import SaveGroundTruth
from lmap_drake.plants.multi import MULTI_KINDS, SaveMultiGroundTruth
from lmap_drake.plants.plant_sim import PlantWorldSim
from lmap_drake.plants.plant_station import GetPlantModel, MakePlantStation
from lmap_drake.plants.scripted import RunScriptedPull
from lmap_drake.scenario import DumpScenario, Scenario
from lmap_drake.viz import SaveDepth, SaveLabel, SaveRgb


def RunStationSnapshot(scenario: Scenario, out: Path,
                       progress: Callable[[str], None] = print) -> list[str]:
    """Builds the simulated station with the scenario's plant, holds the arm
    at ``robot.initial_q`` for ``simulation_duration`` s, and writes
    ``scenario.yaml``, ``rgb.png``, ``depth.png`` (colour-mapped metres),
    ``label.png`` and ``scene.html`` (``kind: multi``: also the plant's
    ground truth, ``ground_truth.json`` with a ``fruits`` list, and meshes)."""
    out = Path(out)
    DumpScenario(scenario, out / "scenario.yaml")
    extra = []
    if scenario.plant_scene.kind in MULTI_KINDS:
        progress(f"generating the {scenario.plant_scene.kind} plant")
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
