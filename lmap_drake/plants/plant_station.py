"""The plant station: the generated plant (cached per scenario), the closed
leaf grasp, and ``MakePlantStation`` -- the simulated station
(``lmap_drake.station.MakeStation``) with the scenario's plant added to its
MultibodyPlant. The station itself knows nothing of plants: this module
hands it an ``add_world(plant, scene_graph)`` callback. Also camera0's
renders of it: ``RenderStill`` (the arm held) and ``UnoccludedFruitPixels``
(the fruit alone, the denominator of the visibility fraction)."""
from __future__ import annotations

import dataclasses as dc
import functools

import numpy as np
from pydrake.math import RigidTransform
from pydrake.systems.framework import Diagram

from lmap_drake.plants.config import PlantSceneConfig
from lmap_drake.plants.greenhouse_scene import AddGreenhousePlant
from lmap_drake.plants.mesh_plant_scene import AddMeshPlant
from lmap_drake.plants.scene import AddMultiPlant, AddPlaceholderPlant, AddProceduralPlant
from lmap_drake.plants.multi import MULTI_KINDS
from lmap_drake.scenario import Scenario
from lmap_drake.station.station import MakeStation


@dc.dataclass
class LeafGrasp:
    """A closed grasp to build into the station: the leaf vertices whose
    reference positions, placed by ``X_GA`` (pose of the leaf's reference
    mesh, i.e. of W at the reference, in the gripper-base frame G), fall in
    the box ``size`` (m) centred at ``p_GR`` (between the pads) are fixed to
    the gripper base. ``leaf``: which leaf (``kind: multi``; 0 otherwise)."""
    X_GA: RigidTransform
    p_GR: np.ndarray
    size: np.ndarray
    leaf: int = 0


@functools.lru_cache(maxsize=8)
def _CachedPlantModel(plant_scene_yaml: str, p_WC: tuple):
    from pydrake.common.yaml import yaml_load_typed
    from lmap_drake.plants.generator import GeneratePlant
    cfg = yaml_load_typed(schema=PlantSceneConfig, data=plant_scene_yaml)
    return GeneratePlant(cfg, np.array(p_WC))


@functools.lru_cache(maxsize=8)
def _CachedMultiPlantModel(plant_scene_yaml: str, p_WC: tuple):
    from pydrake.common.yaml import yaml_load_typed
    from lmap_drake.plants.multi_generator import GenerateMultiPlant
    cfg = yaml_load_typed(schema=PlantSceneConfig, data=plant_scene_yaml)
    return GenerateMultiPlant(cfg, np.array(p_WC))


@functools.lru_cache(maxsize=8)
def _CachedGreenhousePlantModel(plant_scene_yaml: str, p_WC: tuple):
    from pydrake.common.yaml import yaml_load_typed
    from lmap_drake.plants.greenhouse import GenerateGreenhousePlant
    cfg = yaml_load_typed(schema=PlantSceneConfig, data=plant_scene_yaml)
    return GenerateGreenhousePlant(cfg, np.array(p_WC))


@functools.lru_cache(maxsize=8)
def _CachedMeshPlantModel(plant_scene_yaml: str, p_WC: tuple, stamps: tuple):
    from pydrake.common.yaml import yaml_load_typed
    from lmap_drake.plants.mesh_plant import BuildMeshPlant
    cfg = yaml_load_typed(schema=PlantSceneConfig, data=plant_scene_yaml)
    return BuildMeshPlant(cfg, np.array(p_WC))


def _AddMulti(kind: str):
    return {"greenhouse": AddGreenhousePlant, "mesh_plant": AddMeshPlant}.get(kind,
                                                                             AddMultiPlant)


def GetPlantModel(scenario: Scenario):
    """The generated plant of a procedural scenario (``PlantModel``) or of a
    ``kind: multi`` one (``MultiPlantModel``); cached, deterministic in the
    scenario; ``kind: greenhouse``: a ``GreenhousePlantModel``; ``kind:
    mesh_plant``: a ``MeshPlantModel`` (cached also per file stamps)."""
    from pydrake.common.yaml import yaml_dump_typed
    kind = scenario.plant_scene.kind
    if kind not in ("procedural",) + MULTI_KINDS:
        raise ValueError("GetPlantModel needs plant_scene.kind: procedural, multi, greenhouse "
                         "or mesh_plant")
    p_WC = scenario.cameras["camera0"].X_PB.GetDeterministicValue().translation()
    cached = {"procedural": _CachedPlantModel, "multi": _CachedMultiPlantModel,
              "greenhouse": _CachedGreenhousePlantModel}.get(kind)
    # the keys that only steer the simulation do not make another plant
    shape = dc.replace(scenario.plant_scene, sleep_distance=0.0, sleep_speed=0.0, fem_threads=0)
    args = (yaml_dump_typed(shape, schema=PlantSceneConfig), tuple(float(x) for x in p_WC))
    if kind == "mesh_plant":
        from lmap_drake.plants.mesh_plant_files import FileStamps
        return _CachedMeshPlantModel(*args, FileStamps(scenario.plant_scene.mesh_plant))
    return cached(*args)


def PlantWorldAdder(scenario: Scenario, leaf_grasp: LeafGrasp | None = None):
    """``add_world(plant, scene_graph)`` for ``MakeStation``: the procedural
    plant (FEM leaf; with ``leaf_grasp`` the grasped leaf region fixed to the
    gripper base) or the rigid placeholder plant."""
    def add(plant, scene_graph) -> None:
        if scenario.plant_scene.kind in MULTI_KINDS:
            handles = _AddMulti(scenario.plant_scene.kind)(
                plant, scene_graph, GetPlantModel(scenario), scenario.plant_scene)
            if leaf_grasp is not None:
                from pydrake.geometry import Box
                plant.mutable_deformable_model().AddFixedConstraint(
                    handles["leaf_body_ids"][leaf_grasp.leaf], plant.GetBodyByName("robotiq_base"),
                    leaf_grasp.X_GA, Box(*leaf_grasp.size), RigidTransform(leaf_grasp.p_GR))
        elif scenario.plant_scene.kind == "procedural":
            handles = AddProceduralPlant(plant, scene_graph, GetPlantModel(scenario),
                                         scenario.plant_scene)
            if leaf_grasp is not None:
                from pydrake.geometry import Box
                plant.mutable_deformable_model().AddFixedConstraint(
                    handles["leaf_body_id"], plant.GetBodyByName("robotiq_base"),
                    leaf_grasp.X_GA, Box(*leaf_grasp.size), RigidTransform(leaf_grasp.p_GR))
        else:
            if leaf_grasp is not None:
                raise ValueError("a leaf grasp needs plant_scene.kind: procedural or multi")
            AddPlaceholderPlant(plant, scenario.plant_scene)
    return add


def MakePlantStation(scenario: Scenario, meshcat=None,
                     leaf_grasp: LeafGrasp | None = None) -> Diagram:
    """The simulated station with the scenario's plant (see the module
    docstring); ports as ``MakeStation``."""
    return MakeStation(scenario, meshcat, add_world=PlantWorldAdder(scenario, leaf_grasp))


def RenderStill(scenario: Scenario, settle: float = 0.0,
                leaf_positions: dict | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """camera0's (rgb HxWx4 uint8, depth HxW float32 m, label HxW int16)
    from the simulated plant station with the arm held at ``robot.initial_q``
    and the gripper at ``robot.initial_gripper_width``, after ``settle``
    simulated seconds (0: the default context, no simulation).
    ``leaf_positions`` {leaf index: (N, 3) vertex positions, W, m, in the
    order of the FEM body's reference positions} poses those leaves (e.g. a
    held leaf, ``leaf.TurnHeldLeaf``); only with ``settle`` 0."""
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource
    builder = DiagramBuilder()
    station = builder.AddSystem(MakePlantStation(scenario))
    q = builder.AddSystem(ConstantVectorSource(scenario.robot.initial_q))
    builder.Connect(q.get_output_port(), station.GetInputPort("ur5.position"))
    g = builder.AddSystem(ConstantVectorSource([scenario.robot.initial_gripper_width]))
    builder.Connect(g.get_output_port(), station.GetInputPort("gripper.position"))
    diagram = builder.Build()
    if settle > 0:
        sim = Simulator(diagram)
        sim.AdvanceTo(settle)
        root = sim.get_context()
    else:
        root = diagram.CreateDefaultContext()
    if leaf_positions:
        if settle > 0:
            raise ValueError("RenderStill: leaf_positions only without settle")
        from lmap_drake.plants.scene import LeafBodyName
        plant = station.GetSubsystemByName("plant")
        dm = plant.deformable_model()
        multi = scenario.plant_scene.kind in MULTI_KINDS
        plant_context = plant.GetMyMutableContextFromRoot(root)
        for j, q in leaf_positions.items():
            body = dm.GetBodyByName(LeafBodyName(multi, j))
            dm.SetPositions(plant_context, body.body_id(),
                            np.asfortranarray(np.asarray(q, float).reshape(-1, 3).T))
    ctx = station.GetMyContextFromRoot(root)

    def image(name):
        return np.array(station.GetOutputPort(f"camera0.{name}_image").Eval(ctx).data)
    return image("rgb"), image("depth")[..., 0], image("label")[..., 0]


def UnoccludedFruitPixels(scenario: Scenario, fruit: int | None = None) -> int:
    """camera0's fruit pixel count with the leaf and robot removed (fruit and
    branch only): the denominator of the visibility fraction. ``kind:
    multi``: the pixels of fruit instance ``fruit`` (None: all fruits)."""
    from pydrake.geometry import MakeRenderEngineVtk, RenderEngineVtkParams
    from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlantConfig
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.sensors import RgbdSensor

    from lmap_drake.labels import FRUIT, DecodeLabels

    builder = DiagramBuilder()
    plant, sg = AddMultibodyPlant(MultibodyPlantConfig(time_step=0.0), builder)
    if scenario.plant_scene.kind in MULTI_KINDS:
        _AddMulti(scenario.plant_scene.kind)(plant, sg, GetPlantModel(scenario),
                                             scenario.plant_scene, with_leaves=False)
    else:
        AddProceduralPlant(plant, sg, GetPlantModel(scenario), scenario.plant_scene,
                           with_leaf=False)
    plant.Finalize()
    cam = scenario.cameras["camera0"]
    sg.AddRenderer(cam.renderer_name, MakeRenderEngineVtk(RenderEngineVtkParams()))
    color, depth = cam.MakeCameras()
    sensor = builder.AddSystem(RgbdSensor(sg.world_frame_id(), cam.X_PB.GetDeterministicValue(),
                                          color, depth))
    builder.Connect(sg.get_query_output_port(), sensor.query_object_input_port())
    diagram = builder.Build()
    ctx = diagram.CreateDefaultContext()
    label = sensor.label_image_output_port().Eval(sensor.GetMyContextFromRoot(ctx))
    cls, inst = DecodeLabels(label.data)
    mask = cls == FRUIT
    if fruit is not None:
        mask &= inst == fruit
    return int(mask.sum())
