"""``MakeStation``: the simulated UR5 cell or the hardware one as a
Diagram with a fixed port contract.

Exported ports (both modes):

- ``ur5.position`` (in, 6): commanded UR5 joint positions, rad.
- ``gripper.position`` (in, 1): commanded 2F-85 opening, m (0 closed, 0.085 open).
- ``ur5.position_measured`` (out, 6): joint positions, rad.
- ``ur5.state_estimated`` (out, 12): joint positions (rad) then velocities (rad/s).
- ``gripper.state_measured`` (out, 3): opening (m), its rate (m/s), and
  whether the gripper reports it stopped on an object while closing (1 or
  0; NaN: the gripper cannot tell, as in simulation).
- ``camera0.rgb_image`` (out, ImageRgba8U), ``camera0.depth_image`` (out,
  ImageDepth32F, metres along the optical axis), ``camera0.label_image`` (out,
  ImageLabel16I, sim only; values per ``lmap_drake.labels``).
- ``ur5.wrist_force`` (out, 3): the force the tool (the 2F-85 and what it
  holds or touches) exerts on the UR5's flange, N, world frame (on
  hardware: the arm's TCP force estimate, base frame). Its value at rest
  is the tool's weight (or, on hardware, the arm's offset): a user zeroes
  it (the controller's force guard, ``planner.max_pull_force``, measures
  from its value at the pre-grasp pose). Optional for a station: without
  it, the guard is off.

The camera pose ``X_WC`` is the scenario's ``cameras.camera0.X_PB`` (eye-to-hand,
fixed), with the Drake camera convention (+z forward, +x right, +y down).
"""
from __future__ import annotations

import numpy as np
from pydrake.geometry import (MakeRenderEngineVtk, Meshcat, MeshcatVisualizer,
                              MeshcatVisualizerParams, PerceptionProperties,
                              RenderEngineVtkParams, RenderLabel, Role)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import (AddMultibodyPlant, MultibodyPlant)
from pydrake.multibody.tree import PdControllerGains
from pydrake.systems.framework import Context, Diagram, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import (ConstantVectorSource, Demultiplexer, MatrixGain,
                                        Multiplexer, StateInterpolatorWithDiscreteDerivative)
from pydrake.systems.sensors import RgbdSensor

from lmap_drake.labels import ROBOT, EncodeLabel
from lmap_drake.scenario import Scenario
from lmap_drake.station.camera_noise import CameraNoise
from lmap_drake.robot import (GRIPPER_JOINTS, UR5_JOINTS, AddUr5AndGripper,
                                      MakeControllerPlant)

STATION_PORTS = {
    "inputs": ["ur5.position", "gripper.position"],
    "outputs": ["ur5.position_measured", "ur5.state_estimated", "gripper.state_measured",
                "camera0.rgb_image", "camera0.depth_image", "camera0.label_image",
                "ur5.wrist_force"],
}


class WristForceSensor(LeafSystem):
    """The simulated wrist force sensor: from the plant's joint reaction
    forces, the force the tool exerts on the flange across the weld joint
    ``joint`` (flange -> ``robotiq_base``), N, world frame. Inputs
    ``reaction_forces`` (the plant's, sampled at its last step) and
    ``body_poses``; output ``wrist_force`` (3)."""

    def __init__(self, plant: MultibodyPlant, joint):
        super().__init__()
        self._joint = joint
        self._reactions = self.DeclareAbstractInputPort(
            "reaction_forces", plant.get_reaction_forces_output_port().Allocate())
        self._poses = self.DeclareAbstractInputPort(
            "body_poses", plant.get_body_poses_output_port().Allocate())
        self.DeclareVectorOutputPort("wrist_force", 3, self._calc)

    def _calc(self, context: Context, output) -> None:
        # F_CJc_Jc: the spatial force on the child (the tool) at Jc, in Jc
        # (indexed by joint; no joint of the station is ever removed)
        F = self._reactions.Eval(context)[int(self._joint.index())]
        X_WC = self._poses.Eval(context)[int(self._joint.child_body().index())]
        R_WJc = X_WC.rotation().multiply(self._joint.frame_on_child().GetFixedPoseInBodyFrame()
                                         .rotation())
        output.SetFromVector(-(R_WJc.multiply(F.translational())))


def _ToolWeld(plant: MultibodyPlant, tool_body_name: str = "robotiq_base"):
    """The joint whose child body is ``tool_body_name`` (the flange weld)."""
    body = plant.GetBodyByName(tool_body_name)
    for index in plant.GetJointIndices():
        joint = plant.get_joint(index)
        if joint.child_body().index() == body.index():
            return joint
    raise ValueError(f"no joint holds {tool_body_name}")


class GravityCompensation(LeafSystem):
    """Feed-forward torques that cancel gravity on the UR5, as its own servo
    does. Inputs ``ur5_state`` (12: q rad, v rad/s) and ``gripper_state`` (4:
    half-openings m, rates m/s); output ``ur5_torque`` (6, N m)."""

    def __init__(self, X_WB: RigidTransform):
        super().__init__()
        self._plant, _, _ = MakeControllerPlant(X_WB)
        self._context = self._plant.CreateDefaultContext()
        self._ur5_state = self.DeclareVectorInputPort("ur5_state", 12)
        self._gripper_state = self.DeclareVectorInputPort("gripper_state", 4)
        self.DeclareVectorOutputPort("ur5_torque", 6, self._calc)

    def _calc(self, context: Context, output) -> None:
        q = np.concatenate([self._ur5_state.Eval(context)[:6],
                            self._gripper_state.Eval(context)[:2]])
        self._plant.SetPositions(self._context, q)
        tau_g = self._plant.CalcGravityGeneralizedForces(self._context)
        output.SetFromVector(-tau_g[:6])


def _LabelRobotGeometry(plant: MultibodyPlant, scene_graph, instances) -> None:
    """Gives every perception geometry of the robot the ROBOT render label."""
    inspector = scene_graph.model_inspector()
    label = RenderLabel(EncodeLabel(ROBOT, 0))
    for instance in instances:
        for body_index in plant.GetBodyIndices(instance):
            body = plant.get_body(body_index)
            for gid in plant.GetVisualGeometriesForBody(body):
                props = inspector.GetPerceptionProperties(gid)
                if props is None:
                    continue
                new = PerceptionProperties(props)
                new.UpdateProperty("label", "id", label)
                scene_graph.RemoveRole(plant.get_source_id(), gid, Role.kPerception)
                scene_graph.AssignRole(plant.get_source_id(), gid, new)


def _MakeSimStation(scenario: Scenario, meshcat: Meshcat | None, add_world) -> Diagram:
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlant(scenario.plant_config, builder)
    robot = scenario.robot
    X_WB = robot.X_WB.GetDeterministicValue()
    ur5, gripper = AddUr5AndGripper(plant, X_WB)
    if add_world is not None:
        add_world(plant, scene_graph)
    for i, name in enumerate(UR5_JOINTS):
        actuator = plant.GetJointActuatorByName(name.replace("_joint", "_motor"), ur5)
        actuator.set_controller_gains(PdControllerGains(p=robot.kp[i], d=robot.kd[i]))
    for name in GRIPPER_JOINTS:
        actuator = plant.GetJointActuatorByName(name.replace("_joint", "_motor"), gripper)
        actuator.set_controller_gains(
            PdControllerGains(p=robot.gripper_kp, d=robot.gripper_kd))
    plant.Finalize()
    for i, name in enumerate(UR5_JOINTS):
        plant.GetJointByName(name, ur5).set_default_angle(robot.initial_q[i])
    for name in GRIPPER_JOINTS:
        plant.GetJointByName(name, gripper).set_default_translation(
            0.5 * robot.initial_gripper_width)
    _LabelRobotGeometry(plant, scene_graph, [ur5, gripper])

    # Arm servo: position command -> desired state (implicit PD) + gravity.
    dt = scenario.plant_config.time_step
    interp = builder.AddNamedSystem(
        "ur5_command_to_state", StateInterpolatorWithDiscreteDerivative(6, dt, True))
    builder.Connect(interp.get_output_port(), plant.get_desired_state_input_port(ur5))
    builder.ExportInput(interp.get_input_port(), "ur5.position")
    if robot.gravity_compensation:
        gravity = builder.AddNamedSystem("ur5_gravity_compensation",
                                         GravityCompensation(X_WB))
        builder.Connect(plant.get_state_output_port(ur5), gravity.get_input_port(0))
        builder.Connect(plant.get_state_output_port(gripper), gravity.get_input_port(1))
        builder.Connect(gravity.get_output_port(), plant.get_actuation_input_port(ur5))
    demux = builder.AddNamedSystem("ur5_state_demux", Demultiplexer([6, 6]))
    builder.Connect(plant.get_state_output_port(ur5), demux.get_input_port())
    builder.ExportOutput(demux.get_output_port(0), "ur5.position_measured")
    builder.ExportOutput(plant.get_state_output_port(ur5), "ur5.state_estimated")
    wrist = builder.AddNamedSystem("ur5_wrist_force", WristForceSensor(plant, _ToolWeld(plant)))
    builder.Connect(plant.get_reaction_forces_output_port(),
                    wrist.GetInputPort("reaction_forces"))
    builder.Connect(plant.get_body_poses_output_port(), wrist.GetInputPort("body_poses"))
    builder.ExportOutput(wrist.get_output_port(), "ur5.wrist_force")

    # Gripper: opening command -> both half-openings; measured opening.
    grip_cmd = builder.AddNamedSystem(
        "gripper_command_to_state", MatrixGain(np.array([[0.5], [0.5], [0.0], [0.0]])))
    builder.Connect(grip_cmd.get_output_port(), plant.get_desired_state_input_port(gripper))
    builder.ExportInput(grip_cmd.get_input_port(), "gripper.position")
    grip_meas = builder.AddNamedSystem(
        "gripper_state_to_opening", MatrixGain(np.array([[1.0, 1.0, 0.0, 0.0],
                                                         [0.0, 0.0, 1.0, 1.0]])))
    builder.Connect(plant.get_state_output_port(gripper), grip_meas.get_input_port())
    no_object_sensing = builder.AddNamedSystem("gripper_object_unknown",
                                               ConstantVectorSource([np.nan]))
    grip_mux = builder.AddNamedSystem("gripper_state_mux", Multiplexer([2, 1]))
    builder.Connect(grip_meas.get_output_port(), grip_mux.get_input_port(0))
    builder.Connect(no_object_sensing.get_output_port(), grip_mux.get_input_port(1))
    builder.ExportOutput(grip_mux.get_output_port(), "gripper.state_measured")

    # Cameras on RenderEngineVtk (EGL, no display needed).
    renderers = set()
    for index, (name, cam) in enumerate(scenario.cameras.items()):
        if cam.renderer_name not in renderers:
            params = RenderEngineVtkParams()
            params.default_clear_color = cam.background.rgba[:3]
            if scenario.lights:
                params.lights = list(scenario.lights)
            scene_graph.AddRenderer(cam.renderer_name, MakeRenderEngineVtk(params))
            renderers.add(cam.renderer_name)
        color_camera, depth_camera = cam.MakeCameras()
        sensor = builder.AddNamedSystem(
            f"rgbd_sensor_{name}",
            RgbdSensor(parent_id=scene_graph.world_frame_id(),
                       X_PB=cam.X_PB.GetDeterministicValue(),
                       color_camera=color_camera, depth_camera=depth_camera))
        builder.Connect(scene_graph.get_query_output_port(),
                        sensor.query_object_input_port())
        rgb_port = sensor.color_image_output_port()
        depth_port = sensor.depth_image_32F_output_port()
        if scenario.camera_noise.enabled:
            info = color_camera.core().intrinsics()
            noise = builder.AddNamedSystem(f"camera_noise_{name}", CameraNoise(
                scenario.camera_noise,
                (info.focal_x(), info.focal_y(), info.center_x(), info.center_y()),
                scenario.random_seed + scenario.camera_noise.seed_offset + 7919 * index,
                info.width(), info.height()))
            builder.Connect(rgb_port, noise.GetInputPort("rgb_in"))
            builder.Connect(depth_port, noise.GetInputPort("depth_in"))
            rgb_port = noise.GetOutputPort("rgb_image")
            depth_port = noise.GetOutputPort("depth_image")
        builder.ExportOutput(rgb_port, f"{name}.rgb_image")
        builder.ExportOutput(depth_port, f"{name}.depth_image")
        builder.ExportOutput(sensor.label_image_output_port(), f"{name}.label_image")

    if meshcat is not None:
        # Published on the plant's step grid: a publish time between steps
        # (the default 1/64 s) makes the simulator stop there too, and the
        # per-step events (a view's capture) then fire at other times than
        # without Meshcat, which changed episodes.
        dt = float(scenario.plant_config.time_step)
        period = dt * max(1, int(np.ceil((1.0 / 64.0) / dt - 1e-9))) if dt > 0 else 1.0 / 64.0
        MeshcatVisualizer.AddToBuilder(builder, scene_graph, meshcat,
                                       MeshcatVisualizerParams(
                                           publish_period=period,
                                           delete_on_initialization_event=False))
    diagram = builder.Build()
    diagram.set_name("station")
    return diagram


def MakeStation(scenario: Scenario, meshcat: Meshcat | None = None,
                hardware: bool = False, add_world=None) -> Diagram:
    """Builds the station Diagram for ``scenario`` with the ports listed in
    this module's docstring. The simulated station contains systems named
    ``plant`` and ``scene_graph``; it holds the UR5 and the 2F-85, and
    ``add_world(plant, scene_graph)``, when given, adds the rest of the world
    before the plant is finalized (the plant world: ``lmap_drake.plants.plant_station``).
    The station itself never imports the plant world."""
    if hardware:
        # Real UR5 + 2F-85 + L515 (lmap_drake/station/hardware/station.py); raises
        # HardwareStationUnavailable when a library or a device is missing.
        # ``meshcat`` is not used on hardware.
        from lmap_drake.station.hardware.station import MakeHardwareStation
        return MakeHardwareStation(scenario)
    return _MakeSimStation(scenario, meshcat, add_world)

