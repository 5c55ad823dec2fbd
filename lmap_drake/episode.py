"""Runs on a station and writes their results to an output folder."""
from __future__ import annotations

from pathlib import Path
from typing import Callable

from pydrake.geometry import Meshcat
from pydrake.systems.analysis import ApplySimulatorConfig, Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from lmap_drake.scenario import DumpScenario, Scenario
from lmap_drake.station import MakeStation
from lmap_drake.viz import SaveDepth, SaveLabel, SaveRgb


def RunStationSnapshot(scenario: Scenario, out: Path, hardware: bool = False,
                       progress: Callable[[str], None] = print) -> list[str]:
    """Builds the station, holds the arm at ``robot.initial_q`` for
    ``simulation_duration`` s, and writes ``scenario.yaml``, ``rgb.png``,
    ``depth.png`` (colour-mapped metres), ``label.png`` and ``scene.html``."""
    out = Path(out)
    DumpScenario(scenario, out / "scenario.yaml")
    progress("building station")
    meshcat = Meshcat()
    builder = DiagramBuilder()
    station = builder.AddNamedSystem("station", MakeStation(scenario, meshcat, hardware))
    q_hold = builder.AddNamedSystem("ur5_hold", ConstantVectorSource(scenario.robot.initial_q))
    builder.Connect(q_hold.get_output_port(), station.GetInputPort("ur5.position"))
    grip = builder.AddNamedSystem(
        "gripper_hold", ConstantVectorSource([scenario.robot.initial_gripper_width]))
    builder.Connect(grip.get_output_port(), station.GetInputPort("gripper.position"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    ApplySimulatorConfig(scenario.simulator_config, simulator)
    progress(f"simulating {scenario.simulation_duration:.2f} s")
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
    return ["scenario.yaml", "rgb.png", "depth.png", "label.png", "scene.html"]


def RunScriptedPullEpisode(scenario: Scenario, out: Path,
                           progress: Callable[[str], None] = print) -> list[str]:
    """Procedural plant world: settle, observe, grasp and pull as given in
    ``plant_scene.pull``, observe again. Writes the snapshot files (before
    the pull), ``rgb_after.png``, ``label_after.png``, ``outcome.json``,
    the ground truth (``ground_truth.json``, ``fruit_W.obj``,
    ``leaf_rest_W.obj``) and ``scene.html`` (Meshcat recording; Meshcat's
    recording does not animate the deformable leaf)."""
    import json
    import time

    from lmap_drake.plants.generator import SaveGroundTruth
    from lmap_drake.plants.simworld import PlantWorldSim, RunScriptedPull

    out = Path(out)
    DumpScenario(scenario, out / "scenario.yaml")
    t0 = time.time()
    meshcat = Meshcat()
    progress("generating the plant and building the station")
    world = PlantWorldSim(scenario, meshcat, progress)
    files = ["scenario.yaml"] + SaveGroundTruth(world.model, out)
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
    progress("outcome: " + ", ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}"
                                      for k, v in outcome.items()))
    return files + ["rgb.png", "depth.png", "label.png", "rgb_after.png", "label_after.png",
                    "outcome.json", "scene.html"]


def RunLmapEpisode(scenario: Scenario, out: Path,
                   progress: Callable[[str], None] = print) -> tuple[list[str], str]:
    """The full LMAP loop in simulation (see ``lmap_drake.evaluation.episode``):
    writes ``scenario.yaml``, ``episode.json``, ``candidates.json``, before/
    after RGB with the segmentation overlaid, ``action_and_shapes.png``,
    the ground truth, ``diagram.svg`` and ``scene.html`` (Meshcat recording
    with leaf snapshots). Returns (files, the episode's status: ``done``,
    ``aborted``, ...)."""
    import json

    from lmap_drake.diagram import WriteDiagramSvg
    from lmap_drake.evaluation.episode import RunEpisode, SaveEpisode
    from lmap_drake.plants.generator import SaveGroundTruth

    out = Path(out)
    DumpScenario(scenario, out / "scenario.yaml")
    meshcat = Meshcat()
    progress("loading the shape template, generating the plant, building the diagram")
    meshcat.StartRecording()
    result = RunEpisode(scenario, meshcat, progress)
    meshcat.StopRecording()
    meshcat.PublishRecording()
    files = ["scenario.yaml"] + SaveEpisode(result, out)
    files += SaveGroundTruth(result.world.model, out)
    SaveRgb(result.images_before["rgb_image"], out / "rgb.png")
    SaveDepth(result.images_before["depth_image"], out / "depth.png")
    SaveLabel(result.images_before["label_image"], out / "label.png")
    SaveRgb(result.images_after["rgb_image"], out / "rgb_after.png")
    SaveLabel(result.images_after["label_image"], out / "label_after.png")
    (out / "outcome.json").write_text(json.dumps(result.record["outcome"], indent=2))
    files += ["rgb.png", "depth.png", "label.png", "rgb_after.png", "label_after.png",
              "outcome.json"]
    files.append("diagram.svg" if WriteDiagramSvg(result.world.diagram, out / "diagram.svg")
                 else "diagram.dot")
    (out / "scene.html").write_text(meshcat.StaticHtml())
    files.append("scene.html")
    r = result.record
    progress(f"episode {r['status']}: {r['message'] or '(no message)'}")
    progress("outcome: " + json.dumps(r["outcome"]))
    if r["shape_initial"] and r["shape_final"]:
        progress(f"Chamfer {r['shape_initial']['chamfer_cm']:.2f} cm -> "
                 f"{r['shape_final']['chamfer_cm']:.2f} cm; wall {r['wall_seconds']:.0f} s")
    return files, str(r["status"])
