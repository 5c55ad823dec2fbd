"""The Perception LeafSystem wired to the simulated station."""
import numpy as np
import pytest
from pydrake.math import RigidTransform
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from lmap_drake.perception.segmentation import SegmenterError
from lmap_drake.scenario import LoadScenario
from lmap_drake.plants.plant_station import MakePlantStation
from lmap_drake.systems.perception import Perception

SMALL = ("cameras: {camera0: {name: camera0, width: 320, height: 240, "
         "focal: !FocalLength {x: 228.4, y: 228.5}, center_x: 160.0, center_y: 120.0, "
         "X_PB: {base_frame: world, translation: [0.25, -0.55, 0.45], "
         "rotation: !Rpy {deg: [-105.0, 0.0, -25.0]}}}}")


def _diagram(segmenter="label", connect_label=True, extra=""):
    # ``extra`` is a later override (a repeated key in one text is an error)
    s = LoadScenario(scenario_text=[SMALL + f"\nperception: {{segmenter: {segmenter}}}",
                                    extra or "{}"])
    builder = DiagramBuilder()
    station = builder.AddSystem(MakePlantStation(s))
    perception = builder.AddSystem(Perception(s.cameras["camera0"], s.perception))
    for port in ("rgb_image", "depth_image") + (("label_image",) if connect_label else ()):
        builder.Connect(station.GetOutputPort(f"camera0.{port}"),
                        perception.GetInputPort(f"camera0.{port}"))
    q = builder.AddSystem(ConstantVectorSource(s.robot.initial_q))
    builder.Connect(q.get_output_port(), station.GetInputPort("ur5.position"))
    g = builder.AddSystem(ConstantVectorSource([0.085]))
    builder.Connect(g.get_output_port(), station.GetInputPort("gripper.position"))
    return builder, s, station, perception


def test_ports_and_docstring():
    _, s, _, p = _diagram()
    ins = {p.get_input_port(i).get_name() for i in range(p.num_input_ports())}
    outs = {p.get_output_port(i).get_name() for i in range(p.num_output_ports())}
    assert ins == {"camera0.rgb_image", "camera0.depth_image", "camera0.label_image",
                   "camera0.X_WC", "ur5.position", "gripper.opening", "capture"}
    assert outs == {"semantic_scene", "fused_semantic_scene", "num_views_fused"}
    import lmap_drake.systems.perception as mod
    for name in ins | outs:
        assert name in mod.__doc__
    assert "metres" in mod.__doc__ and "+z forward" in mod.__doc__


@pytest.mark.parametrize("segmenter", ["label", "color_depth"])
def test_semantic_scene_in_world_frame(segmenter):
    builder, s, _, p = _diagram(segmenter, connect_label=segmenter == "label")
    diagram = builder.Build()
    ctx = diagram.CreateDefaultContext()
    scene = p.GetOutputPort("semantic_scene").Eval(p.GetMyContextFromRoot(ctx))
    assert not scene.is_empty() and "no_fruit_in_view" not in scene.flags
    np.testing.assert_allclose(scene.X_WC,
                               s.cameras["camera0"].X_PB.GetDeterministicValue().GetAsMatrix4())
    # the plant stands around x = 0.5, y = 0 (world, m)
    allp = np.concatenate([scene.branch_points_W, scene.leaf_points_W, scene.fruit_points_W])
    assert np.all(np.abs(allp[:, 0] - 0.5) < 0.12) and np.all(np.abs(allp[:, 1]) < 0.15)


def test_label_segmenter_without_label_port_is_clear_error():
    builder, _, _, p = _diagram("label", connect_label=False)
    diagram = builder.Build()
    ctx = diagram.CreateDefaultContext()
    with pytest.raises(SegmenterError, match="label_image"):
        p.GetOutputPort("semantic_scene").Eval(p.GetMyContextFromRoot(ctx))


def test_camera_pose_port_moves_the_points():
    builder, s, _, p = _diagram()
    diagram = builder.Build()
    ctx = diagram.CreateDefaultContext()
    pc = p.GetMyContextFromRoot(ctx)
    base = p.GetOutputPort("semantic_scene").Eval(pc).fruit_points_W.mean(axis=0)
    X = s.cameras["camera0"].X_PB.GetDeterministicValue()
    p.GetInputPort("camera0.X_WC").FixValue(pc, RigidTransform([0, 0, 1.0]) @ X)
    moved = p.GetOutputPort("semantic_scene").Eval(pc).fruit_points_W.mean(axis=0)
    np.testing.assert_allclose(moved - base, [0, 0, 1.0], atol=1e-3)  # voxel grid shifts


def test_empty_view_gives_flags_not_a_crash():
    # camera looking away from the plant (up into the empty sky)
    away = SMALL.replace("[-105.0, 0.0, -25.0]", "[0.0, 0.0, 0.0]")
    builder, _, _, p = _diagram("color_depth", connect_label=False, extra="\n" + away)
    diagram = builder.Build()
    ctx = diagram.CreateDefaultContext()
    scene = p.GetOutputPort("semantic_scene").Eval(p.GetMyContextFromRoot(ctx))
    assert scene.is_empty()
    assert "empty_scene" in scene.flags and "no_fruit_in_view" in scene.flags


def test_capture_port_fuses_views_during_simulation():
    # the renderer's exact images, so that two captures of one scene agree
    builder, _, _, p = _diagram(extra="{camera_noise: {enabled: false}}")
    counter = builder.AddSystem(ConstantVectorSource([1.0]))
    builder.Connect(counter.get_output_port(), p.GetInputPort("capture"))
    diagram = builder.Build()
    sim = Simulator(diagram)
    pc = p.GetMyContextFromRoot(sim.get_mutable_context())
    fused0 = p.GetOutputPort("fused_semantic_scene").Eval(pc)
    assert fused0.is_empty() and "no_views_fused" in fused0.flags
    sim.AdvanceTo(0.02)
    fused1 = p.GetOutputPort("fused_semantic_scene").Eval(pc)
    assert fused1.num_views == 1 and len(fused1.fruit_points_W) > 0
    sim.AdvanceTo(0.05)  # counter stays at 1: no second capture
    assert p.GetOutputPort("fused_semantic_scene").Eval(pc).num_views == 1
    fused2 = p.CaptureView(pc)  # direct capture of a second view
    assert fused2.num_views == 2 and "fused_views" in fused2.flags
    assert len(fused2.fruit_points_W) == len(fused1.fruit_points_W)  # same view, same voxels
    # Drake copies abstract state at every step's update (and in a Clone of
    # the Context): the copies share the fused scene, which is never changed
    # in place, instead of copying its points.
    clone = p.GetMyContextFromRoot(sim.get_context().Clone())
    assert clone.get_abstract_state(0).get_value().scene is fused2


def test_a_captured_view_is_segmented_once_however_often_it_is_asked_for():
    """Wired as in the episode (station -> ViewRecorder -> Perception): the
    scene of a held view is not segmented again while the station moves on
    (Drake recomputes the port after every step), e.g. when planning asks
    for the view that was fused."""
    from lmap_drake.systems.view_recorder import ViewRecorder
    s = LoadScenario(scenario_text=[SMALL + "\nperception: {segmenter: label}"])
    builder = DiagramBuilder()
    station = builder.AddSystem(MakePlantStation(s))
    p = builder.AddSystem(Perception(s.cameras["camera0"], s.perception))
    builder.Connect(builder.AddSystem(ConstantVectorSource(s.robot.initial_q)).get_output_port(),
                    station.GetInputPort("ur5.position"))
    builder.Connect(builder.AddSystem(ConstantVectorSource([0.085])).get_output_port(),
                    station.GetInputPort("gripper.position"))
    views = builder.AddSystem(ViewRecorder())
    for name in ("rgb_image", "depth_image", "label_image"):
        builder.Connect(station.GetOutputPort(f"camera0.{name}"),
                        views.GetInputPort(f"camera0.{name}"))
        builder.Connect(views.GetOutputPort(name), p.GetInputPort(f"camera0.{name}"))
    for name in ("ur5.state_estimated", "gripper.state_measured"):
        builder.Connect(station.GetOutputPort(name), views.GetInputPort(name))
    builder.Connect(builder.AddSystem(ConstantVectorSource([1.0])).get_output_port(),
                    views.GetInputPort("capture"))
    builder.Connect(views.GetOutputPort("ur5.position"), p.GetInputPort("ur5.position"))
    builder.Connect(views.GetOutputPort("num_views"), p.GetInputPort("capture"))
    sim = Simulator(builder.Build())
    calls = []
    segment = p.segmenter.Segment
    p.segmenter.Segment = lambda *a: calls.append(1) or segment(*a)
    sim.AdvanceTo(0.05)         # captured, then fused
    pc = p.GetMyContextFromRoot(sim.get_context())
    assert p.GetOutputPort("num_views_fused").Eval(pc)[0] == 1 and len(calls) == 1
    for t in (0.1, 0.15):        # the station's state changes at every step
        sim.AdvanceTo(t)
        scene = p.GetOutputPort("semantic_scene").Eval(p.GetMyContextFromRoot(sim.get_context()))
        assert len(scene.fruit_points_W) > 0
    assert len(calls) == 1
    # a different view is segmented
    pc = p.GetMyContextFromRoot(sim.get_context())
    depth = p.GetInputPort("camera0.depth_image").Eval(pc)
    depth.mutable_data[:] += 0.01
    p.GetInputPort("camera0.depth_image").FixValue(pc, depth)
    p.GetOutputPort("semantic_scene").Eval(pc)
    assert len(calls) == 2
