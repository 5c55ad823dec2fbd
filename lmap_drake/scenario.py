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
from pydrake.geometry import LightParameter, Rgba
from pydrake.math import RollPitchYaw
from pydrake.multibody.plant import MultibodyPlantConfig
from pydrake.systems.analysis import SimulatorConfig
from pydrake.systems.sensors import CameraConfig
from pydrake.geometry import SceneGraphConfig

from lmap_drake.paths import DEFAULT_SCENARIO_FILE, DEFAULT_SCENARIO_NAME
from lmap_drake.station.hardware_config import HardwareConfig


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
        default_factory=lambda: [-1.3941, -0.552, 1.9769, 0.1742, -1.4152, -0.1795])
    initial_gripper_width: float = 0.085
    kp: list[float] = dc.field(default_factory=lambda: [8000., 8000., 4000., 600., 600., 300.])
    kd: list[float] = dc.field(default_factory=lambda: [400., 400., 200., 30., 30., 12.])
    gripper_kp: float = 4000.0
    gripper_kd: float = 40.0
    gravity_compensation: bool = True


@dc.dataclass
class BranchConfig:
    """Rigid branch: a vertical cylinder, optionally bowed sideways (m)."""
    radius: float = 0.006
    length: float = 0.5
    bend: float = 0.0
    color: Rgba = dc.field(default_factory=lambda: Rgba(0.33, 0.45, 0.2, 1.0))


@dc.dataclass
class LeafConfig:
    """FEM leaf: blade outline (m), mesh resolution and material.

    Material defaults: E = 10 MPa (leaf lamina is reported at 5-20 MPa),
    Poisson 0.3. The simulated blade is 2 mm thick (two 1 mm tet layers) for
    well-shaped tets, so its ``mass_density`` is an effective 100 kg/m^3,
    which gives a real lamina's ~0.2 kg/m^2. Damping: stiffness-proportional
    ``stiffness_damping`` (s) and mass-proportional ``mass_damping`` (1/s).
    ``clearance``: blade in front of the fruit's front (m); the blade leaves
    the branch ``attach_above_fruit`` above the fruit top and bends down with
    ``bend_radius``."""
    length: float = 0.13
    width: float = 0.075
    shape: str = "ovate"
    petiole_length: float = 0.04
    petiole_width: float = 0.006
    thickness: float = 0.002
    target_tets: int = 1000
    element_size: float = 0.0  # 0 = derived from target_tets
    youngs_modulus: float = 10.0e6
    poissons_ratio: float = 0.3
    mass_density: float = 100.0
    stiffness_damping: float = 0.01
    mass_damping: float = 1.0
    clearance: float = 0.025
    min_fruit_clearance: float = 0.004
    attach_above_fruit: float = 0.012
    bend_radius: float = 0.025
    color: Rgba = dc.field(default_factory=lambda: Rgba(0.2, 0.55, 0.15, 1.0))


@dc.dataclass
class FruitConfig:
    """Pepper shape (see ``lmap_drake.plants.pepper.PepperShape``), colour and
    placement. ``height_on_branch``: fruit centre above the branch base (m);
    ``tilt_deg``: peduncle axis tilt from vertical, about a horizontal axis at
    ``tilt_azimuth_deg`` from the camera direction; ``lean_deg``: a further
    tilt that turns the fruit top toward the branch (the fruit hangs from a
    short peduncle at a stem node, its body pressed away from the stem). The
    fruit sits as close to the branch as ``gap_to_branch`` (m, branch surface
    to fruit surface) allows; the peduncle stalk runs from the fruit top to
    the stem."""
    variant: str = "blocky"
    size: list[float] = dc.field(default_factory=lambda: [0.075, 0.075, 0.085])
    lobes: int = 4
    lobe_depth: float = 0.08
    squareness: float = 2.4
    shoulder: float = 0.12
    taper: float = 0.06
    cone: float = 0.0
    lobe_phase_deg: float = 0.0
    color: Rgba = dc.field(default_factory=lambda: Rgba(0.75, 0.05, 0.05, 1.0))
    stripe_color: Rgba = dc.field(default_factory=lambda: Rgba(0.55, 0.02, 0.02, 1.0))
    stripes: int = 0
    height_on_branch: float = 0.22
    gap_to_branch: float = 0.004
    tilt_deg: float = 10.0
    tilt_azimuth_deg: float = 30.0
    lean_deg: float = 0.0
    peduncle_length: float = 0.015
    peduncle_radius: float = 0.004


@dc.dataclass
class ScriptedPullConfig:
    """A grasp-and-pull given by hand (what ``lmap-drake run`` executes until
    the planner chooses actions). The grasp sits ``grasp_from_tip`` (m) from
    the blade tip along the midrib, ``grasp_v`` (m) to the side of it; the
    gripper approaches along the midrib from beyond the tip with its pads
    ``pregrasp_opening`` (m) apart, closing across the blade. The pull moves
    the TCP ``distance`` (m) along ``direction_W`` in ``duration`` (s), then
    holds for ``hold`` (s)."""
    enabled: bool = True
    grasp_from_tip: float = 0.015
    grasp_v: float = 0.0
    pregrasp_distance: float = 0.05
    pregrasp_opening: float = 0.02
    direction_W: list[float] = dc.field(default_factory=lambda: [-0.57, 0.0, 0.82])
    distance: float = 0.06
    duration: float = 2.0
    hold: float = 0.5


@dc.dataclass
class OutcomeConfig:
    """Thresholds of the ground-truth outcome measures (simulator only).

    ``leaf_damage``: the ``strain_percentile`` of per-tet max principal
    stretch, leaving out tets that touch a constraint, exceeds
    ``tear_stretch``. ``plant_hazard``: the petiole's axial force estimate
    E * A * (stretch - 1), with the median stretch of the ring of petiole
    tets next to the branch attachment, exceeds ``petiole_max_force`` (N;
    15 N is a 12.5 % petiole strain at the default E and cross-section). ``fruit_collision``: a leaf vertex or
    robot geometry comes within ``-fruit_penetration`` of the fruit surface
    (i.e. penetrates it by more than that, m) or touches it with more than
    ``fruit_contact_force`` (N)."""
    tear_stretch: float = 1.10
    strain_percentile: float = 95.0
    petiole_max_force: float = 15.0
    fruit_penetration: float = 0.001
    fruit_contact_force: float = 0.05
    sample_period: float = 0.05


@dc.dataclass
class PlantSceneConfig:
    """The plant in front of the robot. ``kind: procedural`` builds the
    branch, pepper and FEM leaf from the sub-configs, with the leaf swung so
    that it hides ``occlusion`` of the fruit from camera0; ``kind:
    placeholder`` is a cheap rigid scene (branch cylinder, leaf plate,
    pepper mesh) for fast tests. World frame, metres."""
    kind: str = "placeholder"
    name: str = ""
    p_W_branch_base: list[float] = dc.field(default_factory=lambda: [0.5, 0.0, 0.1])
    occlusion: float = 0.85
    fruit_side: float = -1.0
    branch: BranchConfig = dc.field(default_factory=BranchConfig)
    leaf: LeafConfig = dc.field(default_factory=LeafConfig)
    fruit: FruitConfig = dc.field(default_factory=FruitConfig)
    pull: ScriptedPullConfig = dc.field(default_factory=ScriptedPullConfig)
    outcome: OutcomeConfig = dc.field(default_factory=OutcomeConfig)
    # placeholder-only fields
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
class CameraNoiseConfig:
    """The simulated camera's sensor model (``lmap_drake/station/camera_noise.py``),
    applied to camera0's colour and depth images; labels are untouched.
    ``enabled: false`` gives the renderer's perfect images.

    Defaults (an L515 / D4xx-like sensor at the plant's 0.4-0.9 m):

    - ``depth_sigma_0 + depth_sigma_z2 z^2`` (m): 1.5 mm at 0.5 m, 2.6 mm at
      0.8 m, 4.0 mm at 1 m; Intel quotes <= 2.5 mm precision (1 sigma) at
      1 m for the L515 and an RMS error of ~1 mm at 0.5 m growing with z^2 for
      the D415 (2 % at 2 m). ``correlated_fraction`` of the variance-weighted
      noise is smooth over ``correlated_length_px`` (the low-frequency
      "wobble" of time-of-flight and stereo depth).
    - grazing incidence (deg): returns fade out between ``grazing_start_deg``
      and ``grazing_full_deg`` between the ray and the surface normal (dark,
      glancing leaf rims and fruit silhouettes are where an L515 loses depth).
    - ``thin_width_px``: surfaces narrower than this many pixels (a petiole,
      a peduncle, far twigs) lose ``thin_dropout`` of their returns.
    - ``mixed_pixel_fraction`` of the pixels at a depth jump larger than
      ``edge_jump`` (m) become flying pixels between the two surfaces (or
      no return when the far side is empty).
    - ``speckle_dropout``: scattered missing returns anywhere.
    - ``depth_unit``: quantisation, 0.25 mm (the L515's depth unit; D4xx 1 mm).
    - colour: per-scene ``exposure_variation`` (+-15 % gain),
      ``white_balance_variation`` (+-5 % per channel) and
      ``illumination_gradient`` (+-12 % across the image), then per-pixel
      noise sqrt(read_noise^2 + shot_noise^2 I) on the 0-255 scale (about
      2-3 levels, a consumer CMOS in good light).

    ``seed_offset`` is added to the scenario's ``random_seed`` for the
    noise."""
    enabled: bool = True
    depth_sigma_0: float = 0.001
    depth_sigma_z2: float = 0.002
    correlated_fraction: float = 0.5
    correlated_length_px: float = 6.0
    grazing_start_deg: float = 72.0
    grazing_full_deg: float = 86.0
    thin_width_px: float = 3.0
    thin_dropout: float = 0.5
    edge_jump: float = 0.01
    mixed_pixel_fraction: float = 0.3
    speckle_dropout: float = 0.002
    depth_unit: float = 0.00025
    exposure_variation: float = 0.15
    white_balance_variation: float = 0.05
    illumination_gradient: float = 0.12
    read_noise: float = 1.5
    shot_noise: float = 0.15
    seed_offset: int = 0


@dc.dataclass
class PerceptionConfig:
    """Segmentation and point-cloud parameters (paper Sec. III-A-1). See
    ``lmap_drake/perception/``. Lengths in metres."""
    # segnet (the default: trained RGB-D network, no labels) | color_depth
    # (classical colour + depth) | label (the simulator's labels: an oracle
    # for ablations) | grounded_sam (local GroundingDINO + SAM files)
    segmenter: str = "segnet"
    # segnet: weights (relative to the repository root; made by
    # scripts/train_segnet.py) and torch device.
    segnet_weights: str = "models/segnet/segnet.pt"
    segnet_device: str = "cpu"
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
    # Free space from background pixels (every ``background_stride``-th
    # pixel per row and column): their rays passed the plant. A +inf depth
    # (no return) is taken as nothing within ``no_return_free_range`` m
    # (0 = such pixels carve nothing). Right for the simulated camera; on
    # hardware set it to 0: the RealSense client also maps dropouts (dark or
    # glancing surfaces, too close) to +inf, and those would carve the fruit.
    background_stride: int = 2
    no_return_free_range: float = 2.0
    # ... but only where no pixel with a return lies within this many pixels:
    # a narrower no-return patch is a dropout (glancing rim, thin part,
    # speckle) next to a surface, not open space.
    no_return_margin_px: float = 6.0


@dc.dataclass
class ShapeConfig:
    """Branch completion and scene-consistent shape completion (Sec. III-A).

    ``weights_file`` is relative to the repository root (written by
    ``scripts/train_deepsdf.py``); ``mean_latent_file`` is only needed for a
    HortiMapping-style checkpoint. ``method``: ssc | homa | supeps. SSC
    losses measure lengths in ``loss_length_unit`` (m; 0.01 = cm); see
    ``lmap_drake/shape/ssc.py``. ``branch_*``: branch completion (slab
    thickness, radius factor, cylinder mesh resolution, ARAP match distance;
    metres)."""
    weights_file: str = "models/deepsdf/pepper_decoder.pt"
    mean_latent_file: str = ""
    method: str = "ssc"
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
    loss_length_unit: float = 0.01
    push_from_camera: float = 0.01
    max_surface_points: int = 300
    max_negative_points: int = 300
    negative_margin: float = 0.005
    max_negative_candidates: int = 4000
    peduncle_max_distance: float = 0.02
    peduncle_cone_deg: float = 30.0
    refresh_every: int = 25
    mesh_spacing: float = 0.003
    branch_slab: float = 0.01
    branch_radius_factor: float = 1.0
    branch_mesh_res: float = 0.003
    branch_match_distance: float = 0.03


@dc.dataclass
class DeformationConfig:
    """Embedded deformation graph and ARAP solve (Sec. III-B). Lengths in m.

    ``vein_weights``: edge weights for two / one / no midrib endpoints.
    Leaf-to-branch edges use ``leaf_branch_edge_radius`` and
    ``leaf_branch_weight`` (the authors' code: 16 mm, 100; set them to
    ``edge_radius`` and 1 for the paper's single radius rule). A grasp more
    than ``max_grasp_distance`` from the leaf is an error; a handle with no
    leaf node within ``edge_radius`` is tied to its
    ``handle_fallback_neighbors`` nearest leaf nodes. Dense points follow
    their ``interpolation_neighbors`` nearest nodes (within
    ``interpolation_radius``) with Gaussian RBF weights of width
    ``interpolation_sigma``, each node applying its ARAP rotation.
    ``arap_method``: "lbfgs" (L-BFGS with the Laplacian as initial Hessian,
    longer pulls of a direction starting from the shorter one's solution;
    the default) or "plain" (textbook global-local iterations from the
    Laplacian solve); both stop when the relative energy decrease of an
    iteration falls below ``relative_tolerance``."""
    voxel_size: float = 0.005
    edge_radius: float = 0.008
    vein_distance: float = 0.012
    vein_weights: list[float] = dc.field(default_factory=lambda: [3.0, 2.0, 1.0])
    handle_grid: int = 5
    handle_size: float = 0.025
    fixed_branch_distance: float = 0.05
    max_iterations: int = 300
    relative_tolerance: float = 1e-5
    arap_method: str = "lbfgs"
    leaf_branch_edge_radius: float = 0.016
    leaf_branch_weight: float = 100.0
    max_grasp_distance: float = 0.02
    handle_fallback_neighbors: int = 3
    interpolation_neighbors: int = 8
    interpolation_radius: float = 0.05
    interpolation_sigma: float = 0.005


@dc.dataclass
class PlannerConfig:
    """LMAP candidates, checks, visibility and selection (Sec. III-C).

    ``max_energy_per_node`` (m^2; 0 disables): actions whose predicted
    ARAP energy per deformable leaf node exceeds it are rejected as a damage
    risk (the paper's score, normalised over all checked actions, then picks
    among the rest). A deviation from the paper, whose min-max normalised
    score gives energy no absolute meaning (when every candidate is risky it
    still picks one). Per node, because the energy is a sum over the graph
    and grows with leaf size at equal strain. The default is calibrated on
    simulated episodes by ``scripts/calibrate_energy_cap.py``.

    ``force_action`` ([grasp_id, direction_id, distance m]; empty = off):
    execute this candidate of the LMAP table instead of the best-scoring one
    (what-if runs and ``scripts/action_oracle.py``). It must pass the IK and
    robot collision checks; the energy cap, leaf-fruit and early-stop
    verdicts are kept in its ``reason`` but do not stop it."""
    num_grasps: int = 15
    grasp_inset: float = 0.01
    num_directions: int = 14
    max_branch_angle_deg: float = 120.0
    distances: list[float] = dc.field(default_factory=lambda: [0.02, 0.04, 0.06, 0.08])
    early_stop_fraction: float = 0.95
    pregrasp_distance: float = 0.05
    pregrasp_opening: float = 0.035
    grasp_close_width: float = 0.0015
    gripper_close_speed: float = 0.05
    grasp_attach_opening: float = 0.006
    min_branch_distance: float = 0.06
    visibility_voxel: float = 0.003
    collision_margin: float = 0.005
    energy_weight: float = 1.0
    max_energy_per_node: float = 5.9e-7
    force_action: list[float] = dc.field(default_factory=list)
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
            time_step=0.01, discrete_contact_approximation="sap"))
    scene_graph_config: SceneGraphConfig = dc.field(default_factory=SceneGraphConfig)
    robot: RobotConfig = dc.field(default_factory=RobotConfig)
    cameras: typing.Mapping[str, CameraConfig] = dc.field(
        default_factory=lambda: {"camera0": DefaultCameraConfig()})
    camera_noise: CameraNoiseConfig = dc.field(default_factory=CameraNoiseConfig)
    # Lights of the simulated cameras' renderer (Drake ``LightParameter``);
    # empty = the renderer's default headlight at the camera.
    lights: list[LightParameter] = dc.field(default_factory=list)
    plant_scene: PlantSceneConfig = dc.field(default_factory=PlantSceneConfig)
    perception: PerceptionConfig = dc.field(default_factory=PerceptionConfig)
    shape: ShapeConfig = dc.field(default_factory=ShapeConfig)
    deformation: DeformationConfig = dc.field(default_factory=DeformationConfig)
    planner: PlannerConfig = dc.field(default_factory=PlannerConfig)
    hardware: HardwareConfig = dc.field(default_factory=HardwareConfig)


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
                 scenario_text: str | list[str] = "{}") -> Scenario:
    """Loads a scenario: defaults, then ``scenario_name`` from ``filename``,
    then the YAML overrides in ``scenario_text`` (a list: applied in order).

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
    texts = [scenario_text] if isinstance(scenario_text, str) else list(scenario_text)
    for text in texts:
        if not text or text.strip() in ("", "{}"):
            continue
        try:
            raw = _RawYaml(text)
        except Exception as err:
            raise ScenarioError(f"--scenario_text is not valid YAML: {err}") from err
        try:
            result = yaml_load_typed(schema=Scenario, data=text, defaults=result)
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
    need(s.plant_scene.kind in ("placeholder", "procedural"),
         f"plant_scene.kind '{s.plant_scene.kind}' unknown; use 'procedural' or 'placeholder'")
    need(0.0 <= s.plant_scene.occlusion <= 1.0, "plant_scene.occlusion must be in [0, 1]")
    need(s.plant_scene.leaf.shape in ("ovate", "elliptic"),
         "plant_scene.leaf.shape must be 'ovate' or 'elliptic'")
    need(0.06 <= s.plant_scene.leaf.length <= 0.16,
         "plant_scene.leaf.length must be in [0.06, 0.16] m")
    need(s.perception.segmenter in ("segnet", "label", "color_depth", "grounded_sam"),
         f"perception.segmenter '{s.perception.segmenter}' unknown")
    need(s.planner.method in ("lmap", "random", "upward", "min_overlap"),
         f"planner.method '{s.planner.method}' unknown")
    fa = s.planner.force_action
    need(len(fa) in (0, 3) and (not fa or (float(fa[0]).is_integer() and
                                           float(fa[1]).is_integer() and fa[2] > 0)),
         "planner.force_action must be empty or [grasp_id, direction_id, distance m], "
         f"got {list(fa)}")
    need(not fa or s.planner.method == "lmap",
         "planner.force_action picks an LMAP candidate: it needs planner.method 'lmap'")
    need(s.simulation_duration > 0, "simulation_duration must be > 0 s")


def DumpScenario(s: Scenario, filename: str | Path) -> None:
    """Writes the resolved scenario (all fields) as YAML."""
    Path(filename).write_text(yaml_dump_typed(s, schema=Scenario))
