"""Scenario configuration: dataclasses loaded with Drake's ``yaml_load_typed``.

A scenario file holds named scenarios at top level (``Defaults``,
``OneOfEverything``, ...), in the style of Drake's ``examples/hardware_sim``.
Unknown keys are errors; the message names the key path and the file.

Units: metres, seconds, radians unless a field name says otherwise
(``*_deg``, ``*_cm``). Frames: ``W`` world, ``B`` robot base, ``C`` camera.
"""
import collections.abc

import dataclasses as dc
import typing
from pathlib import Path

import numpy as np
from pydrake.common.schema import Rotation, Transform
from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed
from pydrake.geometry import Rgba
from pydrake.math import RollPitchYaw
from pydrake.multibody.plant import MultibodyPlantConfig
from pydrake.systems.analysis import SimulatorConfig
from pydrake.systems.sensors import CameraConfig
from pydrake.geometry import SceneGraphConfig

from lmap_drake.paths import DEFAULT_SCENARIO_FILE, DEFAULT_SCENARIO_NAME


def _transform(xyz, rpy_deg, base_frame: str | None = None) -> Transform:
    t = Transform()
    t.base_frame = base_frame
    t.translation = np.asarray(xyz, dtype=float)
    t.rotation = Rotation(RollPitchYaw(np.deg2rad(rpy_deg)))
    return t


# L515-like colour intrinsics: the 1024x768 depth intrinsics measured on an
# L515 (fx 730.8, fy 731.1, cx 528.6, cy 408.2) scaled by 0.625 to 640x480.
L515_640x480 = dict(width=640, height=480, fx=456.75, fy=456.94, cx=330.38, cy=255.13)


def DefaultCameraConfig() -> CameraConfig:
    """Eye-to-hand RGB-D camera facing the plant from -y, tilted 15 deg down."""
    c = CameraConfig()
    c.name = "camera0"
    c.width = L515_640x480["width"]
    c.height = L515_640x480["height"]
    c.focal = CameraConfig.FocalLength(x=L515_640x480["fx"], y=L515_640x480["fy"])
    c.center_x = L515_640x480["cx"]
    c.center_y = L515_640x480["cy"]
    c.clipping_near = 0.01
    c.clipping_far = 10.0
    c.z_near = 0.25  # L515 minimum range
    c.z_far = 9.0
    c.X_PB = _transform([0.5, -0.6, 0.47], [-105.0, 0.0, 0.0], "world")
    c.renderer_name = "vtk"
    c.renderer_class = "RenderEngineVtk"
    c.background = Rgba(0.85, 0.87, 0.9, 1.0)
    c.rgb = True
    c.depth = True
    c.label = True
    c.fps = 10.0
    return c


@dc.dataclass
class RobotConfig:
    """UR5 + Robotiq 2F-85 placement, initial state and the simulated joint
    servo (Drake's implicit PD on the plant plus gravity compensation)."""
    X_WB: Transform = dc.field(
        default_factory=lambda: _transform([0.0, 0.0, 0.0], [0.0, 0.0, 180.0]))
    initial_q: list[float] = dc.field(
        default_factory=lambda: [2.0, -1.9, 1.9, -1.571, -1.571, 0.0])
    initial_gripper_width: float = 0.085
    kp: list[float] = dc.field(default_factory=lambda: [8000., 8000., 4000., 600., 600., 300.])
    kd: list[float] = dc.field(default_factory=lambda: [400., 400., 200., 30., 30., 12.])
    gripper_kp: float = 4000.0
    gripper_kd: float = 40.0
    gravity_compensation: bool = True


@dc.dataclass
class PlantSceneConfig:
    """The plant in front of the robot (rigid placeholders until the
    procedural plant world lands). Positions in world frame, metres."""
    kind: str = "placeholder"
    p_W_branch_base: list[float] = dc.field(default_factory=lambda: [0.5, 0.0, 0.1])
    branch_length: float = 0.5
    branch_radius: float = 0.006
    fruit_center_W: list[float] = dc.field(default_factory=lambda: [0.5, -0.045, 0.33])
    fruit_size: list[float] = dc.field(default_factory=lambda: [0.075, 0.075, 0.085])
    fruit_lobes: int = 4
    fruit_color: Rgba = dc.field(default_factory=lambda: Rgba(0.75, 0.05, 0.05, 1.0))
    leaf_center_W: list[float] = dc.field(default_factory=lambda: [0.5, -0.1, 0.355])
    leaf_size: list[float] = dc.field(default_factory=lambda: [0.10, 0.002, 0.065])
    leaf_color: Rgba = dc.field(default_factory=lambda: Rgba(0.2, 0.55, 0.15, 1.0))
    branch_color: Rgba = dc.field(default_factory=lambda: Rgba(0.35, 0.5, 0.2, 1.0))


@dc.dataclass
class PerceptionConfig:
    """Segmentation and point-cloud parameters (paper Sec. III-A-1). See
    ``lmap_drake/perception/``. Lengths in metres."""
    segmenter: str = "label"  # label | color_depth | grounded_sam
    depth_cut: float = 1.5
    dbscan_eps: float = 0.008
    dbscan_min_points: int = 30
    voxel_size: float = 0.003
    # Statistical outlier removal (open3d): neighbours and std-dev ratio.
    outlier_neighbors: int = 20
    outlier_std_ratio: float = 2.0
    # color_depth: structures narrower than this are branch candidates; green
    # curved regions may be reported as (green) fruit.
    branch_max_width: float = 0.035
    detect_green_fruit: bool = True
    # grounded_sam: local files only (GroundingDINO config .py and checkpoint,
    # SAM checkpoint), never downloaded; SAM model type; torch device.
    grounded_sam_config: str = ""
    grounded_sam_checkpoint: str = ""
    sam_checkpoint: str = ""
    sam_model_type: str = "vit_h"
    grounded_sam_device: str = "cpu"
    box_threshold: float = 0.25
    text_threshold: float = 0.25
    nms_threshold: float = 0.8
    # view fusion: a new instance joins an earlier one within this distance.
    fusion_match_distance: float = 0.008


@dc.dataclass
class ShapeConfig:
    """Branch completion and scene-consistent shape completion (Sec. III-A)."""
    weights_file: str = "models/deepsdf/pepper_decoder.pt"
    latent_size: int = 32
    free_space_voxel: float = 0.003
    w_sur: float = 1.0
    w_neg: float = 2.0
    w_ped: float = 0.1
    w_reg: float = 1.0
    w_neg_completed_branch: float = 0.1
    reestimate_w_ped: float = 0.01
    reestimate_w_neg_completed_branch: float = 0.01
    learning_rate: float = 0.01
    iterations: int = 300
    num_peduncle_points: int = 10


@dc.dataclass
class DeformationConfig:
    """Embedded deformation graph and ARAP solve (Sec. III-B)."""
    voxel_size: float = 0.005
    edge_radius: float = 0.008
    vein_distance: float = 0.012
    vein_weights: list[float] = dc.field(default_factory=lambda: [3.0, 2.0, 1.0])
    handle_grid: int = 5
    handle_size: float = 0.025
    fixed_branch_distance: float = 0.05
    max_iterations: int = 300
    relative_tolerance: float = 1e-5


@dc.dataclass
class PlannerConfig:
    """LMAP candidates, checks, visibility and selection (Sec. III-C)."""
    num_grasps: int = 15
    grasp_inset: float = 0.01
    num_directions: int = 14
    max_branch_angle_deg: float = 120.0
    distances: list[float] = dc.field(default_factory=lambda: [0.02, 0.04, 0.06, 0.08])
    early_stop_fraction: float = 0.95
    pregrasp_distance: float = 0.05
    visibility_voxel: float = 0.003
    collision_margin: float = 0.005
    energy_weight: float = 1.0
    method: str = "lmap"  # lmap | random | upward | min_overlap


@dc.dataclass
class Scenario:
    """Everything one run needs. See ``diagrams/default.yaml``."""
    random_seed: int = 0
    simulation_duration: float = 1.0
    simulator_config: SimulatorConfig = dc.field(
        default_factory=lambda: SimulatorConfig(
            max_step_size=0.01, use_error_control=False, accuracy=1e-2,
            target_realtime_rate=0.0))
    plant_config: MultibodyPlantConfig = dc.field(
        default_factory=lambda: MultibodyPlantConfig(
            time_step=0.005, discrete_contact_approximation="sap"))
    scene_graph_config: SceneGraphConfig = dc.field(default_factory=SceneGraphConfig)
    robot: RobotConfig = dc.field(default_factory=RobotConfig)
    cameras: typing.Mapping[str, CameraConfig] = dc.field(
        default_factory=lambda: {"camera0": DefaultCameraConfig()})
    plant_scene: PlantSceneConfig = dc.field(default_factory=PlantSceneConfig)
    perception: PerceptionConfig = dc.field(default_factory=PerceptionConfig)
    shape: ShapeConfig = dc.field(default_factory=ShapeConfig)
    deformation: DeformationConfig = dc.field(default_factory=DeformationConfig)
    planner: PlannerConfig = dc.field(default_factory=PlannerConfig)
    hardware: "HardwareConfig" = dc.field(default_factory=lambda: HardwareConfig())


class ScenarioError(ValueError):
    """A scenario file or override could not be loaded."""


def _schema_fields(schema) -> dict | None:
    """Field name -> type for a dataclass or a Drake-bound struct, else None."""
    if dc.is_dataclass(schema):
        hints = typing.get_type_hints(schema)
        return {f.name: hints.get(f.name) for f in dc.fields(schema)}
    fields = getattr(schema, "__fields__", None)
    if fields is not None:
        return {f.name: f.type for f in fields}
    return None


def _unknown_keys(schema, data, path: str) -> list[str]:
    """Dotted paths of keys in ``data`` that ``schema`` does not know."""
    fields = _schema_fields(schema)
    if fields is None or not isinstance(data, dict):
        origin = typing.get_origin(schema)
        if origin in (dict, typing.Mapping, collections.abc.Mapping) and isinstance(data, dict):
            value_type = typing.get_args(schema)[1]
            out = []
            for k, v in data.items():
                out += _unknown_keys(value_type, v, f"{path}.{k}")
            return out
        return []
    out = []
    for key, value in data.items():
        if key.startswith("_"):
            continue
        if key not in fields:
            out.append(f"{path}.{key}" if path else key)
        else:
            out += _unknown_keys(fields[key], value, f"{path}.{key}" if path else key)
    return out


def _RawYaml(text: str):
    """Plain-YAML parse that keeps Drake's tagged values (``!Rpy``) as maps."""
    import yaml

    class _Loader(yaml.SafeLoader):
        pass

    def _tagged(loader, suffix, node):
        if isinstance(node, yaml.MappingNode):
            return loader.construct_mapping(node, deep=True)
        if isinstance(node, yaml.SequenceNode):
            return loader.construct_sequence(node, deep=True)
        return loader.construct_scalar(node)

    _Loader.add_multi_constructor("!", _tagged)
    return yaml.load(text, Loader=_Loader)


def _explain(err: Exception, raw: dict | None, root: str, where: str) -> ScenarioError:
    msg = str(err)
    if raw is not None:
        bad = _unknown_keys(Scenario, raw, root)
        if bad:
            msg = (f"unknown key(s) {', '.join(bad)} in {where}; valid keys are the "
                   f"fields of the Scenario dataclasses in lmap_drake/scenario.py "
                   f"(Drake said: {err})")
            return ScenarioError(msg)
    return ScenarioError(f"could not load scenario from {where}: {msg}")


def LoadScenario(*, filename: str | Path | None = None,
                 scenario_name: str | None = None,
                 scenario_text: str = "{}") -> Scenario:
    """Loads a scenario: defaults, then ``scenario_name`` from ``filename``,
    then the YAML overrides in ``scenario_text``.

    Raises ScenarioError naming the file and the unknown key on bad input.
    """
    result = Scenario()
    if filename is not None:
        path = Path(filename)
        if not path.exists():
            raise ScenarioError(f"scenario file not found: {path}")
        text = path.read_text()
        raw_all = _RawYaml(text) or {}
        name = scenario_name or DEFAULT_SCENARIO_NAME
        if name not in raw_all:
            raise ScenarioError(
                f"scenario '{name}' not in {path}; it has: {', '.join(raw_all) or 'none'}")
        try:
            result = yaml_load_typed(schema=Scenario, data=text, child_name=name,
                                     defaults=result)
        except Exception as err:  # Drake raises RuntimeError
            raise _explain(err, raw_all[name], name, f"{path} (scenario '{name}')") from err
    if scenario_text and scenario_text.strip() not in ("", "{}"):
        try:
            raw = _RawYaml(scenario_text)
        except Exception as err:
            raise ScenarioError(f"--scenario_text is not valid YAML: {err}") from err
        try:
            result = yaml_load_typed(schema=Scenario, data=scenario_text, defaults=result)
        except Exception as err:
            raise _explain(err, raw, "", "--scenario_text") from err
    Validate(result)
    return result


def LoadDefaultScenario() -> Scenario:
    return LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name=DEFAULT_SCENARIO_NAME)


def Validate(s: Scenario) -> None:
    """Checks values the type system cannot; raises ScenarioError."""
    def need(cond, msg):
        if not cond:
            raise ScenarioError(msg)
    need(len(s.robot.initial_q) == 6, "robot.initial_q needs 6 joint values (rad)")
    need(len(s.robot.kp) == 6 and len(s.robot.kd) == 6, "robot.kp and robot.kd need 6 values")
    need(0.0 <= s.robot.initial_gripper_width <= 0.085,
         "robot.initial_gripper_width must be in [0, 0.085] m")
    need("camera0" in s.cameras, "cameras must contain 'camera0' (the pipeline's camera)")
    for name, cam in s.cameras.items():
        need(cam.name == name, f"cameras.{name}.name must equal its key '{name}'")
        need(cam.depth and cam.rgb, f"cameras.{name} needs rgb and depth enabled")
    need(s.plant_scene.kind in ("placeholder",),
         f"plant_scene.kind '{s.plant_scene.kind}' unknown; use 'placeholder'")
    need(s.perception.segmenter in ("label", "color_depth", "grounded_sam"),
         f"perception.segmenter '{s.perception.segmenter}' unknown")
    need(s.planner.method in ("lmap", "random", "upward", "min_overlap"),
         f"planner.method '{s.planner.method}' unknown")
    need(s.simulation_duration > 0, "simulation_duration must be > 0 s")


def DumpScenario(s: Scenario, filename: str | Path) -> None:
    """Writes the resolved scenario (all fields) as YAML."""
    Path(filename).write_text(yaml_dump_typed(s, schema=Scenario))


# Imported last: with an eager lmap_drake/station/__init__.py, importing
# hardware_config at the top would import this module half-initialised.
# Drake's yaml reads the dataclass field's type object, hence the fix-up.
from lmap_drake.station.hardware_config import HardwareConfig  # noqa: E402
Scenario.__dataclass_fields__["hardware"].type = HardwareConfig
