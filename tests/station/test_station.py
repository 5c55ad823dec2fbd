"""The simulated station: port contract, servo behaviour, rendering."""
import numpy as np
import pytest
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource, TrajectorySource
from pydrake.trajectories import PiecewisePolynomial

from lmap_drake.labels import BRANCH, FRUIT, LEAF, DecodeLabels
from lmap_drake.paths import DEFAULT_SCENARIO_FILE
from lmap_drake.planning.ik import SolveTcpIk
from lmap_drake.scenario import LoadScenario
from lmap_drake.station import STATION_PORTS, MakeStation
from lmap_drake.plants.plant_station import MakePlantStation
from lmap_drake.robot import MakeControllerPlant
from lmap_drake.errors import HardwareStationUnavailable


def _port_names(diagram):
    ins = [diagram.get_input_port(i).get_name() for i in range(diagram.num_input_ports())]
    outs = [diagram.get_output_port(i).get_name() for i in range(diagram.num_output_ports())]
    return ins, outs


@pytest.mark.parametrize("name", ["Defaults", "OneOfEverything"])
def test_station_builds_with_exactly_the_contract_ports(name):
    s = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name=name)
    ins, outs = _port_names(MakeStation(s))
    assert sorted(ins) == sorted(STATION_PORTS["inputs"])
    assert sorted(outs) == sorted(STATION_PORTS["outputs"])


def test_hardware_request_gives_clear_error(scenario, monkeypatch):
    import sys
    monkeypatch.setitem(sys.modules, "pyrealsense2", None)   # never reach a device
    with pytest.raises(HardwareStationUnavailable, match="hardware station"):
        MakeStation(scenario, hardware=True)


def _closed_loop(scenario, q_source, gripper_width):
    builder = DiagramBuilder()
    station = builder.AddSystem(MakePlantStation(scenario))
    src = builder.AddSystem(q_source)
    builder.Connect(src.get_output_port(), station.GetInputPort("ur5.position"))
    grip = builder.AddSystem(ConstantVectorSource([gripper_width]))
    builder.Connect(grip.get_output_port(), station.GetInputPort("gripper.position"))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = station.GetMyContextFromRoot(simulator.get_mutable_context())
    return simulator, station, context


def _tcp(station, context):
    plant = station.GetSubsystemByName("plant")
    pc = station.GetSubsystemContext(plant, context)
    return plant.CalcRelativeTransform(pc, plant.world_frame(), plant.GetFrameByName("tcp"))


def test_held_command_keeps_arm_still(scenario):
    sim, station, ctx = _closed_loop(
        scenario, ConstantVectorSource(scenario.robot.initial_q), 0.085)
    p0 = _tcp(station, ctx).translation()
    q0 = station.GetOutputPort("ur5.position_measured").Eval(ctx).copy()
    sim.AdvanceTo(0.5)
    assert np.linalg.norm(_tcp(station, ctx).translation() - p0) < 1e-3
    assert np.abs(station.GetOutputPort("ur5.position_measured").Eval(ctx) - q0).max() < 1e-3
    state = station.GetOutputPort("ur5.state_estimated").Eval(ctx)
    assert state.shape == (12,) and np.abs(state[6:]).max() < 1e-2


def test_wrist_force_reads_the_tools_weight_at_rest(scenario):
    sim, station, ctx = _closed_loop(
        scenario, ConstantVectorSource(scenario.robot.initial_q), 0.085)
    sim.AdvanceTo(0.3)
    plant = station.GetSubsystemByName("plant")
    tool = plant.GetModelInstanceByName("robotiq_2f85")
    mass = sum(plant.get_body(b).default_mass() for b in plant.GetBodyIndices(tool))
    f = station.GetOutputPort("ur5.wrist_force").Eval(ctx)
    # the tool hangs from the flange: its weight, straight down (world z up)
    assert mass > 0.5
    assert np.allclose(f, [0.0, 0.0, -9.81 * mass], atol=0.02 * 9.81 * mass)


def test_gripper_opens_and_closes(scenario):
    sim, station, ctx = _closed_loop(
        scenario, ConstantVectorSource(scenario.robot.initial_q), 0.0)
    assert station.GetOutputPort("gripper.state_measured").Eval(ctx)[0] == pytest.approx(0.085)
    sim.AdvanceTo(1.0)
    assert station.GetOutputPort("gripper.state_measured").Eval(ctx)[0] < 0.002
    scenario.robot.initial_gripper_width = 0.0
    sim, station, ctx = _closed_loop(
        scenario, ConstantVectorSource(scenario.robot.initial_q), 0.085)
    sim.AdvanceTo(1.0)
    assert station.GetOutputPort("gripper.state_measured").Eval(ctx)[0] > 0.083


def test_tcp_tracks_slow_cartesian_pull(scenario):
    """A 6 cm straight pull over 3 s, in front of the plant: the simulated TCP
    stays within 5 mm of the Cartesian line at every sample."""
    X_WB = scenario.robot.X_WB.GetDeterministicValue()
    controller_plant, _, _ = MakeControllerPlant(X_WB)
    R_WT = RotationMatrix.MakeXRotation(-np.pi / 2)  # approach along +y_W
    p0, dp, T = np.array([0.45, -0.22, 0.40]), np.array([0.0, -0.06, 0.0]), 3.0
    times = np.linspace(0.0, T, 31)
    qs = []
    seed = np.array([0.0, -1.5, 1.5, -1.57, -1.57, 0.0])
    for t in times:
        r = SolveTcpIk(controller_plant, RigidTransform(R_WT, p0 + dp * t / T), seed)
        assert r.success, r.reason
        qs.append(r.q)
        seed = r.q
    scenario.robot.initial_q = list(qs[0])
    traj = PiecewisePolynomial.CubicShapePreserving(times, np.array(qs).T, True)
    sim, station, ctx = _closed_loop(scenario, TrajectorySource(traj), 0.085)
    errors = []
    for t in np.arange(0.0, T + 0.5, 0.05):
        sim.AdvanceTo(t)
        expected = p0 + dp * min(t, T) / T
        errors.append(np.linalg.norm(_tcp(station, ctx).translation() - expected))
    assert max(errors) < 5e-3
    # and it really moved 6 cm
    assert np.linalg.norm(_tcp(station, ctx).translation() - p0) > 0.055


def test_camera_images(scenario):
    station = MakePlantStation(scenario)
    ctx = station.CreateDefaultContext()
    rgb = station.GetOutputPort("camera0.rgb_image").Eval(ctx)
    depth = station.GetOutputPort("camera0.depth_image").Eval(ctx).data[..., 0]
    label = station.GetOutputPort("camera0.label_image").Eval(ctx).data
    cam = scenario.cameras["camera0"]
    assert rgb.data.shape == (cam.height, cam.width, 4)
    assert depth.dtype == np.float32 and depth.shape == (cam.height, cam.width)
    cls, _ = DecodeLabels(label)
    assert (cls == FRUIT).sum() > 0, "the fruit's label must be visible"
    plant_px = np.isin(cls, [BRANCH, LEAF, FRUIT])
    assert plant_px.sum() > 1000
    # the default (noisy) camera loses some returns at rims and thin parts
    returns = np.isfinite(depth[plant_px])
    assert 0.9 < returns.mean() < 1.0
    # The plant is 0.45-0.75 m from the camera along its optical axis.
    assert 0.4 < depth[plant_px][returns].min() and depth[plant_px][returns].max() < 0.8
    # the renderer's own image (camera model off) has a return on every plant pixel
    import dataclasses as dc
    ideal = dc.replace(scenario, camera_noise=dc.replace(scenario.camera_noise, enabled=False))
    st2 = MakePlantStation(ideal)
    d2 = st2.GetOutputPort("camera0.depth_image").Eval(st2.CreateDefaultContext()).data[..., 0]
    assert np.all(np.isfinite(d2[plant_px]))
    # Fruit pixels are red, leaf pixels green.
    assert rgb.data[cls == FRUIT][:, 0].mean() > rgb.data[cls == FRUIT][:, 1].mean() + 50
    assert rgb.data[cls == LEAF][:, 1].mean() > rgb.data[cls == LEAF][:, 0].mean() + 30


def test_meshcat_publishes_on_the_plant_step_grid():
    """With Meshcat the simulator still stops only on the plant's steps: a
    publish between steps (Meshcat's default 1/64 s) made it stop there,
    the per-step events (view captures) fired at other times, and an
    episode with Meshcat differed from the same episode without it."""
    from pydrake.geometry import Meshcat
    from pydrake.systems.framework import EventStatus
    from lmap_drake.plants.plant_sim import PlantWorldSim
    s = LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name="Defaults")
    world = PlantWorldSim(s, meshcat=Meshcat())
    times = []

    def monitor(context):
        times.append(context.get_time())
        return EventStatus.DidNothing()
    world.simulator.set_monitor(monitor)
    world.Hold(0.1)
    dt = s.plant_config.time_step
    assert len(times) >= 10
    off = [t for t in times if abs(t / dt - round(t / dt)) > 1e-6]
    assert not off, off[:5]
