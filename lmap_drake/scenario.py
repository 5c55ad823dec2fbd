"""Scenario configuration: dataclasses loaded with Drake's ``yaml_load_typed``.

A scenario file holds named scenarios at top level (``Defaults``,
``OneOfEverything``, ...), in the style of Drake's ``examples/hardware_sim``.
Unknown keys are errors; the message names the key path and the file.

Units: metres, seconds, radians unless a field name says otherwise
(``*_deg``, ``*_cm``). Frames: ``W`` world, ``B`` robot base, ``C`` camera.
"""
import collections.abc
import dataclasses as dc
import re
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

from lmap_drake.errors import InputError
from lmap_drake.paths import DEFAULT_SCENARIO_FILE, DEFAULT_SCENARIO_NAME
from lmap_drake.planning.config import PlannerConfig, PlannerConfigError, ValidatePlannerConfig
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
    the stem.

    ``mesh_file`` (OBJ, PLY or STL; empty = the procedural pepper above)
    puts a given pepper mesh in its place, placed the same way: the file's
    +z is the fruit's peduncle axis, the peduncle leaves at the top, units
    are metres times ``mesh_scale`` (0.001 for a file in millimetres); the
    file's origin is ignored (the fruit is centred on its volume centroid).
    ``peduncle_file`` (optional, same frame and units): the stalk, rendered
    and labelled as branch, joined to the branch from its far end.
    ``peduncle_point`` (optional, file frame and units): where the peduncle
    leaves the fruit; default: nearest the peduncle mesh, else where the +z
    axis through the centroid leaves the surface. The shape keys (``size``
    ... ``lobe_phase_deg``, ``stripes``) are ignored for a file fruit. See
    ``lmap_drake/plants/fruit_mesh.py`` for the checks and repairs.

    Wider procedural family (defaults keep the old shapes and stalk):
    ``dimple`` (relative stem-cavity depth, 0-0.45) whose centre is tilted
    ``cavity_offset_deg`` off the axis toward ``cavity_phase_deg``;
    ``bend`` (1/m) bends the body sideways toward ``bend_phase_deg``;
    ``peduncle_curved: true`` makes the peduncle a curved tube of
    ``peduncle_length`` whose end leaves the axis by ``peduncle_angle_deg``
    toward ``peduncle_azimuth_deg`` (labelled branch, joined to the branch
    from its end), instead of the straight stalk."""
    variant: str = "blocky"
    size: list[float] = dc.field(default_factory=lambda: [0.075, 0.075, 0.085])
    lobes: int = 4
    lobe_depth: float = 0.08
    squareness: float = 2.4
    shoulder: float = 0.12
    taper: float = 0.06
    cone: float = 0.0
    lobe_phase_deg: float = 0.0
    dimple: float = 0.0
    cavity_offset_deg: float = 0.0
    cavity_phase_deg: float = 0.0
    bend: float = 0.0
    bend_phase_deg: float = 0.0
    peduncle_curved: bool = False
    peduncle_angle_deg: float = 0.0
    peduncle_azimuth_deg: float = 0.0
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
    mesh_file: str = ""
    peduncle_file: str = ""
    mesh_scale: float = 1.0
    peduncle_point: list[float] = dc.field(default_factory=list)


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
class MultiFruitConfig:
    """One fruit of a ``kind: multi`` plant. It hangs from its own side
    shoot that leaves the main stem ``height`` (m, above the branch base) on
    the ``side`` (+1 / -1: +/- the lateral direction seen from camera0) and
    reaches just past the fruit (``shoot_extra`` m beyond the peduncle,
    rising ``shoot_rise_deg``). ``num_leaves`` (0-2) leaves sit on that
    shoot and are swung to hide ``occlusion`` of the fruit from camera0
    (counting every leaf of the plant; ignored with 0 leaves). ``fruit``:
    shape and colour as ``plant_scene.fruit`` (its ``tilt_deg``,
    ``tilt_azimuth_deg``, ``peduncle_*`` and ``mesh_file`` / ``mesh_scale``
    / ``peduncle_file`` / ``peduncle_point`` (a pepper mesh from a file, as
    for ``kind: procedural``) are used; ``height_on_branch``,
    ``gap_to_branch`` and ``lean_deg`` are not)."""
    height: float = 0.25
    side: float = 1.0
    occlusion: float = 0.7
    num_leaves: int = 1
    shoot_extra: float = 0.01
    shoot_rise_deg: float = 20.0
    fruit: FruitConfig = dc.field(default_factory=FruitConfig)


def _DefaultMultiFruits() -> list:
    def one(height, side, occlusion, leaves, color, size):
        f = MultiFruitConfig(height=height, side=side, occlusion=occlusion, num_leaves=leaves)
        f.fruit.color = Rgba(*color, 1.0)
        f.fruit.stripe_color = Rgba(*[0.7 * c for c in color], 1.0)
        f.fruit.size = list(size)
        return f
    return [one(0.13, 1.0, 0.8, 2, (0.75, 0.05, 0.05), (0.07, 0.07, 0.08)),
            one(0.24, -1.0, 0.6, 1, (0.95, 0.75, 0.05), (0.065, 0.065, 0.075)),
            one(0.35, 1.0, 0.0, 0, (0.95, 0.45, 0.05), (0.06, 0.06, 0.07))]


@dc.dataclass
class MultiPlantConfig:
    """``plant_scene.kind: multi``: a main stem (``plant_scene.branch``,
    base ``plant_scene.p_W_branch_base``) with one side shoot per fruit in
    ``fruits`` (2-4) and ``num_leaves`` (2-6) FEM leaves shaped by
    ``plant_scene.leaf``: the fruits' ``num_leaves`` first, the rest on the
    stem above the top fruit, swung outward by ``free_leaf_swing_deg``.
    Leaves keep ``leaf_gap`` (m) from each other, from every fruit
    (``plant_scene.leaf.min_fruit_clearance``) and from the stem and the
    other shoots at rest. ``leaf_leaf_contact: true`` turns on Drake's
    deformable-deformable contact between leaves; off by default: with these
    thin two-layer leaves it does not keep a leaf from passing through
    another and costs 10-40x per step while in contact (measured with drake
    1.51.1, see tests/plants/test_multi_contact.py). World frame, metres."""
    fruits: list[MultiFruitConfig] = dc.field(default_factory=_DefaultMultiFruits)
    num_leaves: int = 4
    shoot_radius: float = 0.004
    leaf_gap: float = 0.003
    free_leaf_swing_deg: float = 55.0
    leaf_leaf_contact: bool = False


@dc.dataclass
class PlantSceneConfig:
    """The plant in front of the robot. ``kind: procedural`` builds the
    branch, pepper and FEM leaf from the sub-configs, with the leaf swung so
    that it hides ``occlusion`` of the fruit from camera0; ``kind:
    placeholder`` is a cheap rigid scene (branch cylinder, leaf plate,
    pepper mesh) for fast tests; ``kind: multi`` a plant with several fruits
    on side shoots and several FEM leaves (``multi``,
    ``lmap_drake/plants/multi.py``). World frame, metres.

    ``sleep_distance`` / ``sleep_speed``: a leaf at rest (every vertex
    slower than ``sleep_speed``, m/s), not held and farther than
    ``sleep_distance`` (m) from the robot's collision surfaces is frozen
    (Drake's ``DeformableModel.Disable``: its FEM is not computed) and woken
    as soon as the robot comes within that distance or it is grasped, as a
    physics engine puts bodies to sleep (``PlantWorldSim``; 0 = every leaf
    always simulated). Leaf-leaf contact (``multi.leaf_leaf_contact``)
    keeps every leaf awake. The check runs every 10 ms step, on robot
    surface samples 1 cm apart (4 mm on the gripper): 3 cm covers the
    samples' gaps and the robot's largest move in a step (at most 1.2 cm measured
    in the multi-fruit suite); on ``three_fruits_default`` 3 cm gave the
    same outcome as 8 cm (petiole force equal to 10 digits) in 178 s
    instead of 222 s.

    ``fem_threads``: threads for the leaves' FEM (Drake's
    ``DeformableModel`` parallelism; 0 = one per CPU, or the
    ``LMAP_DRAKE_THREADS`` an evaluation worker is given). The result does
    not depend on it (leaf vertices after 0.5 s of four awake leaves are
    bit-equal on 1 and 2 threads); 2 threads cut a step with four awake
    leaves from 49-50 to 38-40 ms on this 2-core machine."""
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
    multi: MultiPlantConfig = dc.field(default_factory=MultiPlantConfig)
    sleep_distance: float = 0.03
    sleep_speed: float = 0.002
    fem_threads: int = 0
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
    dbscan_min_points: int = 15
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
    # speckle) next to a surface, not open space. The simulated camera's
    # dropouts (camera_noise) all lie within 2.83 px of a return (60k
    # dropout pixels in the 26 scenes of the three suites; fruit 1.4 px,
    # leaf and branch 2.0); at 6 px the guard also withheld the 8 mm of free
    # space beside every silhouette, and fits bulged sideways into it.
    no_return_margin_px: float = 3.0
    # Flying pixels (depth between a nearer and a farther neighbour, each
    # more than this apart, m; 0 = keep all) are dropped before
    # de-projection: they float in the gap between a leaf and the fruit.
    flying_pixel_jump: float = 0.005
    # Robot self-filter: plant points within this distance (m) of the robot's
    # collision surfaces at the view's joints are dropped (a gripper pixel
    # mislabelled leaf, fruit or branch is not plant; 0 = keep all).
    robot_filter_distance: float = 0.01


@dc.dataclass
class ShapeConfig:
    """Branch completion and scene-consistent shape completion (Sec. III-A).

    ``weights_file`` is relative to the repository root (written by
    ``scripts/train_deepsdf.py``); ``mean_latent_file`` is only needed for a
    HortiMapping-style checkpoint. ``method``: ssc | homa | supeps. SSC
    losses measure lengths in ``loss_length_unit`` (m; 0.01 = cm); see
    ``lmap_drake/shape/ssc.py`` (also for ``peduncle_huber`` (m),
    ``peduncle_moves_scale``, ``peduncle_follow_axis``, ``peduncle_slide``,
    ``peduncle_base_distance`` (m):
    the robust peduncle term, and ``init_from_observation`` /
    ``init_scale_bounds``: the start scale and centre from the observed
    points; ``rotation_lr_scale``: the rotation's share of the Adam step,
    ``reestimate_rotation_lr_scale`` the same for the re-estimate after the
    action; ``rotation_hold_steps``: the first SSC estimate keeps the
    rotation still for this many Adam steps, 0 = off;
    ``reestimate_rotation_hold_steps`` the same for the re-estimate;
    ``reestimate_w_rot``: the re-estimate's pull toward upright, 0 = off). ``branch_*``: branch completion (slab
    thickness, radius factor, cylinder mesh resolution, ARAP match distance;
    metres). ``leaf_split_angle_deg`` (plants with several fruits): touching leaves
    (one cluster of points) are told apart where their surfaces meet at more
    than this angle (``perception.points.SplitTouchingLeaves``; 0 = leaf
    instances as clustered). ``reuse_tolerance`` (m; plants with several
    fruits): a fruit whose points and surroundings in a new view match an
    earlier fit's within this distance (95 % of the points both ways, the
    sensor's noise between two captures) keeps that fit instead of a new
    one (``shape.completion.FitMemo``; 0 = always fit again).
    ``fruit_volume_cm3``: the typical volume of the variety (cm^3; 0 = the
    template's own mean shape, about 170 cm^3): every SSC and HoMa-style fit
    starts at the template scaled to it (``shape.ssc.PriorScale``). With a
    tenth of a fruit in view the fitted size stays near the start, so a lab
    that knows its variety should set it (see the README's *Your own pepper
    mesh*). ``min_fruit_points`` (plants with several fruits): the smallest fruit
    instance completed, in voxels of ``perception.voxel_size`` (20 at 3 mm:
    1.8 cm², about 5 % of a 7 cm pepper's outline; measured with
    ``scripts/eval_fruit_detection.py``)."""
    weights_file: str = "models/deepsdf/pepper_decoder.pt"
    mean_latent_file: str = ""
    method: str = "ssc"
    latent_size: int = 32
    free_space_voxel: float = 0.003
    leaf_split_angle_deg: float = 15.0
    reuse_tolerance: float = 0.005
    min_fruit_points: int = 20
    w_sur: float = 1.0
    w_neg: float = 2.0
    w_ped: float = 0.1
    w_reg: float = 1.0
    w_neg_completed_branch: float = 0.1
    reestimate_w_ped: float = 0.01
    reestimate_w_neg_completed_branch: float = 0.01
    rotation_lr_scale: float = 0.3
    reestimate_rotation_lr_scale: float = 1.0
    reestimate_w_rot: float = 0.0
    reestimate_rotation_hold_steps: int = 50
    rotation_hold_steps: int = 50
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
    peduncle_huber: float = 0.005
    peduncle_moves_scale: bool = False
    peduncle_follow_axis: bool = False
    peduncle_slide: bool = True
    peduncle_base_distance: float = 0.01
    init_from_observation: bool = False
    fruit_volume_cm3: float = 0.0
    w_rot: float = 0.0
    init_scale_bounds: list[float] = dc.field(default_factory=lambda: [0.5, 2.0])
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
    branch_edge_weight: float = 1.0
    max_grasp_distance: float = 0.02
    handle_fallback_neighbors: int = 3
    interpolation_neighbors: int = 8
    interpolation_radius: float = 0.05
    interpolation_sigma: float = 0.005


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


class ScenarioError(InputError, ValueError):
    """A scenario file or override could not be loaded, or holds a bad value.
    The message names the key path and the file (or ``--scenario_text``)."""


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
    origin = typing.get_origin(schema)
    if origin in (list, typing.List, collections.abc.Sequence) and isinstance(data, list):
        item_type = typing.get_args(schema)[0] if typing.get_args(schema) else None
        out = []
        for i, v in enumerate(data):
            out += _unknown_keys(item_type, v, f"{path}[{i}]")
        return out
    if fields is None or not isinstance(data, dict):
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


def _bad_scalars(schema, data, path: str) -> list[str]:
    """Dotted paths of scalars in ``data`` that cannot be the number or
    boolean ``schema`` asks for (e.g. ``abc`` for a float), with the value."""
    if typing.get_origin(schema) is typing.Union or type(schema).__name__ == "UnionType":
        args = [a for a in typing.get_args(schema) if a is not type(None)]
        if data is None:
            return []
        if len(args) == 1:
            schema = args[0]
    origin = typing.get_origin(schema)
    if origin in (list, typing.List, collections.abc.Sequence) and isinstance(data, list):
        item_type = typing.get_args(schema)[0] if typing.get_args(schema) else None
        return [b for i, v in enumerate(data) for b in _bad_scalars(item_type, v, f"{path}[{i}]")]
    if origin in (dict, typing.Mapping, collections.abc.Mapping) and isinstance(data, dict):
        value_type = typing.get_args(schema)[1]
        return [b for k, v in data.items() for b in _bad_scalars(value_type, v, f"{path}.{k}")]
    fields = _schema_fields(schema)
    if fields is not None:
        if not isinstance(data, dict):
            return []
        return [b for k, v in data.items() if k in fields
                for b in _bad_scalars(fields[k], v, f"{path}.{k}" if path else k)]
    if schema in (float, int) and not isinstance(data, (dict, list)):
        ok = not isinstance(data, bool)
        if ok and isinstance(data, str):
            try:
                (float if schema is float else int)(data)
            except ValueError:
                ok = False
        elif ok and schema is int and isinstance(data, float):
            ok = data.is_integer()
        if not ok:
            return [f"{path} = {data!r} (expected {'a number' if schema is float else 'an integer'})"]
    if schema is bool and not isinstance(data, (bool, dict, list)):
        return [f"{path} = {data!r} (expected true or false)"]
    return []


def _RawYaml(text: str, where: str = "the YAML text"):
    """Plain-YAML parse that keeps Drake's tagged values (``!Rpy``) as maps.
    A duplicate key or malformed YAML raises ScenarioError naming ``where``
    (Drake's loader would silently keep the last duplicate)."""
    import yaml

    class _Loader(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            if isinstance(node, yaml.MappingNode):
                seen: dict = {}
                for key_node, _ in node.value:
                    if key_node.tag == "tag:yaml.org,2002:merge":
                        continue
                    key = key_node.value if isinstance(key_node, yaml.ScalarNode) else None
                    if key is None:
                        continue
                    line = key_node.start_mark.line + 1
                    if key in seen:
                        raise ScenarioError(
                            f"duplicate key '{key}' in {where} (line {line}; first at line "
                            f"{seen[key]})")
                    seen[key] = line
            return super().construct_mapping(node, deep=deep)

    def _tagged(loader, suffix, node):
        if isinstance(node, yaml.MappingNode):
            return loader.construct_mapping(node, deep=True)
        if isinstance(node, yaml.SequenceNode):
            return loader.construct_sequence(node, deep=True)
        return loader.construct_scalar(node)

    _Loader.add_multi_constructor("!", _tagged)
    try:
        return yaml.load(text, Loader=_Loader)
    except yaml.YAMLError as err:
        detail = " ".join(str(err).replace('in "<unicode string>", ', "").split())
        raise ScenarioError(f"{where} is not valid YAML: {detail}") from None


def _explain(err: Exception, raw: dict | None, root: str, where: str) -> ScenarioError:
    msg = " ".join(str(err).split())
    if raw is not None:
        bad = _unknown_keys(Scenario, raw, root)
        if bad:
            msg = (f"unknown key(s) {', '.join(bad)} in {where}; valid keys are the "
                   f"fields of the Scenario dataclasses in lmap_drake/scenario.py "
                   f"(Drake said: {msg})")
            return ScenarioError(msg)
        bad = _bad_scalars(Scenario, raw, root)
        if bad:
            return ScenarioError(f"could not load scenario from {where}: bad value(s): "
                                 f"{'; '.join(bad)} (Drake said: {msg})")
    return ScenarioError(f"could not load scenario from {where}: {msg}")


def _ReadScenarioFile(path: Path) -> str:
    if not path.exists():
        raise ScenarioError(f"scenario file not found: {path}")
    if path.is_dir():
        raise ScenarioError(f"scenario file {path} is a directory, not a YAML file")
    try:
        return path.read_text()
    except UnicodeDecodeError:
        raise ScenarioError(f"scenario file {path} is not a UTF-8 text file") from None
    except OSError as err:
        raise ScenarioError(f"cannot read scenario file {path}: {err.strerror or err}") from None


def IsEmptyOverride(text: str | None) -> bool:
    """True when a ``--scenario_text`` overrides nothing (empty or ``{}``)."""
    return not text or text.strip() in ("", "{}")


def LoadScenario(*, filename: str | Path | None = None,
                 scenario_name: str | None = None,
                 scenario_text: str | list[str] = "{}", bare: bool = False) -> Scenario:
    """Loads a scenario: defaults, then ``scenario_name`` from ``filename``,
    then the YAML overrides in ``scenario_text`` (a list: applied in order),
    then ``Validate``. With ``bare`` the file holds one scenario at its top
    level (a run's ``scenario.yaml``, written by ``DumpScenario``).

    Raises ScenarioError naming the key path and the file (or
    ``--scenario_text``) on any bad input: a missing, unreadable or malformed
    file, duplicate or unknown keys, wrong types, bad values.
    """
    result = Scenario()
    sources: list[tuple[dict, str]] = []
    if filename is not None:
        path = Path(filename)
        text = _ReadScenarioFile(path)
        raw_all = _RawYaml(text, str(path))
        if raw_all is None:
            raw_all = {}
        if not isinstance(raw_all, dict):
            raise ScenarioError(f"{path}: the top level must map scenario names to "
                                f"scenarios, got a {type(raw_all).__name__}")
        if bare:
            raw_all = {"": raw_all}
        name = "" if bare else (scenario_name or DEFAULT_SCENARIO_NAME)
        if name not in raw_all:
            have = ", ".join(map(str, raw_all)) or "none"
            raise ScenarioError(f"scenario '{name}' not in {path}; it has: {have}")
        where = f"{path} (scenario '{name}')"
        if raw_all[name] is not None and not isinstance(raw_all[name], dict):
            raise ScenarioError(f"{where}: a scenario must be a map of sections, got "
                                f"{raw_all[name]!r}")
        if bare:
            where = str(path)
        try:
            result = (yaml_load_typed(schema=Scenario, data=text, defaults=result) if bare else
                      yaml_load_typed(schema=Scenario, data=text, child_name=name,
                                      defaults=result))
        except Exception as err:  # Drake raises RuntimeError
            raise _explain(err, raw_all[name], name, where) from None
        sources.append((raw_all[name] or {}, where))
    texts = [scenario_text] if isinstance(scenario_text, str) else list(scenario_text)
    for text in texts:
        if IsEmptyOverride(text):
            continue
        raw = _RawYaml(text, "--scenario_text")
        if not isinstance(raw, dict):
            raise ScenarioError(f"--scenario_text must be a YAML map such as "
                                f"\"{{planner: {{energy_weight: 0.5}}}}\", got {text!r}")
        try:
            result = yaml_load_typed(schema=Scenario, data=text, defaults=result)
        except Exception as err:
            raise _explain(err, raw, "", "--scenario_text") from None
        sources.append((raw, "--scenario_text"))
    Validate(result, sources)
    return result


def LoadDefaultScenario() -> Scenario:
    return LoadScenario(filename=DEFAULT_SCENARIO_FILE, scenario_name=DEFAULT_SCENARIO_NAME)


# Value rules for Validate: key path -> rule. Rules: ">0", ">=0", ">=1",
# "(lo,hi)" / "[lo,hi]" (open / closed ends), "finite"; "Nx<rule>" = a
# list of N values each obeying <rule>, "+x<rule>" = a non-empty list.
# Every float anywhere in the scenario's own dataclasses must be finite.
_RULES = {
    "random_seed": ">=0",
    "simulation_duration": ">0",
    "robot.initial_q": "6xfinite",
    "robot.kp": "6x>=0",
    "robot.kd": "6x>=0",
    "robot.initial_gripper_width": "[0,0.085]",
    "robot.gripper_kp": ">=0",
    "robot.gripper_kd": ">=0",
    "plant_scene.p_W_branch_base": "3xfinite",
    "plant_scene.occlusion": "(0,1)",
    "plant_scene.branch.radius": ">0",
    "plant_scene.branch.length": ">0",
    "plant_scene.leaf.length": "[0.06,0.16]",
    "plant_scene.leaf.width": ">0",
    "plant_scene.leaf.petiole_length": ">0",
    "plant_scene.leaf.petiole_width": ">0",
    "plant_scene.leaf.thickness": ">0",
    "plant_scene.leaf.target_tets": "[100,20000]",
    "plant_scene.leaf.element_size": ">=0",
    "plant_scene.leaf.youngs_modulus": ">0",
    "plant_scene.leaf.poissons_ratio": "[0,0.5)",
    "plant_scene.leaf.mass_density": ">0",
    "plant_scene.leaf.stiffness_damping": ">=0",
    "plant_scene.leaf.mass_damping": ">=0",
    "plant_scene.leaf.clearance": ">=0",
    "plant_scene.leaf.min_fruit_clearance": ">=0",
    "plant_scene.leaf.attach_above_fruit": ">=0",
    "plant_scene.leaf.bend_radius": ">0",
    "plant_scene.fruit.size": "3x>0",
    "plant_scene.fruit.lobes": ">=0",
    "plant_scene.fruit.stripes": ">=0",
    "plant_scene.fruit.height_on_branch": ">0",
    "plant_scene.fruit.gap_to_branch": ">=0",
    "plant_scene.fruit.peduncle_length": ">0",
    "plant_scene.fruit.peduncle_radius": ">0",
    "plant_scene.fruit.mesh_scale": ">0",
    "plant_scene.pull.pregrasp_distance": ">0",
    "plant_scene.pull.pregrasp_opening": "(0,0.085]",
    "plant_scene.pull.direction_W": "3xfinite",
    "plant_scene.pull.distance": ">0",
    "plant_scene.pull.duration": ">0",
    "plant_scene.pull.hold": ">=0",
    "plant_scene.outcome.tear_stretch": ">0",
    "plant_scene.outcome.strain_percentile": "(0,100]",
    "plant_scene.outcome.petiole_max_force": ">0",
    "plant_scene.outcome.fruit_penetration": ">=0",
    "plant_scene.outcome.fruit_contact_force": ">=0",
    "plant_scene.outcome.sample_period": ">0",
    "plant_scene.sleep_distance": ">=0",
    "plant_scene.sleep_speed": ">=0",
    "plant_scene.fem_threads": ">=0",
    "plant_scene.branch_length": ">0",
    "plant_scene.branch_radius": ">0",
    "plant_scene.fruit_center_W": "3xfinite",
    "plant_scene.fruit_size": "3x>0",
    "plant_scene.fruit_lobes": ">=0",
    "plant_scene.leaf_center_W": "3xfinite",
    "plant_scene.leaf_size": "3x>0",
    "perception.depth_cut": ">0",
    "perception.dbscan_eps": ">0",
    "perception.dbscan_min_points": ">=1",
    "perception.voxel_size": ">0",
    "perception.outlier_neighbors": ">=1",
    "perception.outlier_std_ratio": ">0",
    "perception.branch_max_width": ">0",
    "perception.box_threshold": "[0,1]",
    "perception.text_threshold": "[0,1]",
    "perception.nms_threshold": "[0,1]",
    "perception.fusion_match_distance": ">=0",
    "perception.robot_filter_distance": ">=0",
    "perception.background_stride": ">=1",
    "perception.no_return_free_range": ">=0",
    "shape.latent_size": ">=1",
    "shape.free_space_voxel": ">0",
    "shape.leaf_split_angle_deg": ">=0",
    "shape.reuse_tolerance": ">=0",
    "shape.min_fruit_points": ">=1",
    "shape.w_sur": ">=0",
    "shape.w_neg": ">=0",
    "shape.w_ped": ">=0",
    "shape.w_reg": ">=0",
    "shape.w_neg_completed_branch": ">=0",
    "shape.reestimate_w_ped": ">=0",
    "shape.reestimate_w_neg_completed_branch": ">=0",
    "shape.learning_rate": ">0",
    "shape.iterations": ">=1",
    "shape.num_peduncle_points": ">=1",
    "shape.loss_length_unit": ">0",
    "shape.max_surface_points": ">=1",
    "shape.max_negative_points": ">=1",
    "shape.negative_margin": ">=0",
    "shape.max_negative_candidates": ">=1",
    "shape.peduncle_max_distance": ">0",
    "shape.peduncle_cone_deg": "(0,180]",
    "shape.peduncle_huber": ">=0",
    "shape.peduncle_base_distance": ">=0",
    "shape.w_rot": ">=0",
    "shape.rotation_lr_scale": ">0",
    "shape.reestimate_rotation_lr_scale": ">0",
    "shape.reestimate_w_rot": ">=0",
    "shape.reestimate_rotation_hold_steps": ">=0",
    "shape.rotation_hold_steps": ">=0",
    "shape.init_scale_bounds": "2x>0",
    "shape.refresh_every": ">=1",
    "shape.mesh_spacing": ">0",
    "shape.branch_slab": ">0",
    "shape.branch_radius_factor": ">0",
    "shape.branch_mesh_res": ">0",
    "shape.branch_match_distance": ">0",
    "deformation.voxel_size": ">0",
    "deformation.edge_radius": ">0",
    "deformation.vein_distance": ">=0",
    "deformation.vein_weights": "3x>0",
    "deformation.handle_grid": ">=1",
    "deformation.handle_size": ">0",
    "deformation.fixed_branch_distance": ">0",
    "deformation.max_iterations": ">=1",
    "deformation.relative_tolerance": ">0",
    "deformation.leaf_branch_edge_radius": ">0",
    "deformation.leaf_branch_weight": ">0",
    "deformation.max_grasp_distance": ">0",
    "deformation.handle_fallback_neighbors": ">=1",
    "deformation.interpolation_neighbors": ">=1",
    "deformation.interpolation_radius": ">0",
    "deformation.interpolation_sigma": ">0",
    "perception.no_return_margin_px": ">=0",
    "perception.flying_pixel_jump": ">=0",
    "camera_noise.depth_sigma_0": ">=0",
    "camera_noise.depth_sigma_z2": ">=0",
    "camera_noise.correlated_fraction": "[0,1]",
    "camera_noise.correlated_length_px": ">=0",
    "camera_noise.grazing_start_deg": "[0,90]",
    "camera_noise.grazing_full_deg": "[0,90]",
    "camera_noise.thin_width_px": ">=0",
    "camera_noise.thin_dropout": "[0,1]",
    "camera_noise.edge_jump": ">0",
    "camera_noise.mixed_pixel_fraction": "[0,1]",
    "camera_noise.speckle_dropout": "[0,1]",
    "camera_noise.depth_unit": ">=0",
    "camera_noise.exposure_variation": "[0,1)",
    "camera_noise.white_balance_variation": "[0,1)",
    "camera_noise.illumination_gradient": "[0,1)",
    "camera_noise.read_noise": ">=0",
    "camera_noise.shot_noise": ">=0",
}
_ENUMS = {
    "plant_scene.kind": ("placeholder", "procedural", "multi"),
    "plant_scene.leaf.shape": ("ovate", "elliptic"),
    "plant_scene.fruit.variant": ("blocky", "elongated", "conical"),  # plants.pepper.VARIANTS
    "shape.method": ("ssc", "homa", "supeps"),                       # shape.completion.METHODS
    "deformation.arap_method": ("lbfgs", "plain"),
    "perception.segmenter": ("segnet", "color_depth", "label", "grounded_sam"),
    "perception.sam_model_type": ("vit_h", "vit_l", "vit_b"),
}


def _Get(obj, path: str):
    for part in path.split("."):
        obj = getattr(obj, part)
    return obj


def _InRaw(raw, path: str) -> bool:
    """True if the dotted ``path`` (or a prefix of it holding a non-map) is
    written in the raw YAML map ``raw``."""
    node = raw
    for part in path.split("."):
        m = re.fullmatch(r"(.*)\[(\d+)\]", part)      # a list item: key[i]
        key, index = (m.group(1), int(m.group(2))) if m else (part, None)
        if not isinstance(node, dict):
            return True
        if key not in node:
            return False
        node = node[key]
        if index is not None:
            if not isinstance(node, list):
                return True
            if index >= len(node):
                return False
            node = node[index]
    return True


def _IsNumber(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


def _RuleError(v, rule: str) -> str:
    """'' if the scalar ``v`` obeys ``rule``, else what is wrong."""
    if not _IsNumber(v):
        return f"must be a number, got {v!r}"
    if not np.isfinite(v):
        return f"must be finite, got {v}"
    if rule == "finite":
        return ""
    if rule.startswith(">="):
        lo = float(rule[2:])
        return "" if v >= lo else f"must be >= {rule[2:]}, got {v}"
    if rule.startswith(">"):
        lo = float(rule[1:])
        return "" if v > lo else f"must be > {rule[1:]}, got {v}"
    lo_s, hi_s = rule[1:-1].split(",")
    lo, hi = float(lo_s), float(hi_s)
    ok = (v > lo if rule[0] == "(" else v >= lo) and (v < hi if rule[-1] == ")" else v <= hi)
    return "" if ok else f"must be in {rule}, got {v}"


def _FiniteTransform(X) -> bool:
    try:
        if not X.IsDeterministic():
            return True
        return bool(np.all(np.isfinite(X.GetDeterministicValue().GetAsMatrix4())))
    except Exception:  # noqa: BLE001 - Drake refuses a non-finite rotation
        return False


def Validate(s: Scenario, sources: typing.Sequence[tuple[dict, str]] = ()) -> None:
    """Checks values the type system cannot (list lengths, ranges,
    enumerations, finiteness, consistency) before anything is built; raises
    ScenarioError naming the key path and where it was set. ``sources``:
    (raw YAML map, description) in the order they were applied."""
    def where(path: str) -> str:
        for raw, desc in reversed(list(sources)):
            if _InRaw(raw, path):
                return desc
        return "the built-in defaults"

    def fail(path: str, msg: str):
        raise ScenarioError(f"{path} {msg} (set in {where(path)})")

    def need(cond, path: str, msg: str):
        if not cond:
            fail(path, msg)

    # Every number of our own dataclasses is finite (NaN passes comparisons).
    def walk(obj, path):
        for f in dc.fields(obj):
            v = getattr(obj, f.name)
            p = f"{path}.{f.name}" if path else f.name
            if dc.is_dataclass(v):
                walk(v, p)
            elif _IsNumber(v) and not np.isfinite(v):
                fail(p, f"must be finite, got {v}")
            elif isinstance(v, (list, tuple)):
                for i, x in enumerate(v):
                    if _IsNumber(x) and not np.isfinite(x):
                        fail(p, f"must be finite, got {list(v)} (item {i})")
            elif isinstance(v, Transform) and not _FiniteTransform(v):
                fail(p, "must be a finite pose (translation and rotation)")
    walk(s, "")

    for path, rule in _RULES.items():
        v = _Get(s, path)
        m = re.fullmatch(r"(\d+|\+)x(.*)", rule)
        if m:
            n, item = m.groups()
            if not isinstance(v, (list, tuple)):
                fail(path, f"must be a list, got {v!r}")
            if n == "+":
                need(len(v) >= 1, path, f"needs at least one value, got {list(v)}")
            else:
                need(len(v) == int(n), path, f"needs {n} values, got {len(v)}: {list(v)}")
            for x in v:
                err = _RuleError(x, item)
                if err:
                    fail(path, f"values {err.replace('must', 'must each')} in {list(v)}")
        else:
            err = _RuleError(v, rule)
            if err:
                fail(path, err)
    try:
        ValidatePlannerConfig(s.planner)
    except PlannerConfigError as err:
        fail(err.key, err.detail)
    for path, choices in _ENUMS.items():
        v = _Get(s, path)
        need(v in choices, path, f"'{v}' unknown; choose one of {', '.join(choices)}")

    cn = s.camera_noise
    need(cn.grazing_start_deg <= cn.grazing_full_deg, "camera_noise.grazing_start_deg",
         f"must be <= grazing_full_deg ({cn.grazing_full_deg}), got {cn.grazing_start_deg}")
    need("camera0" in s.cameras, "cameras",
         "must contain 'camera0' (the pipeline's camera)")
    for name, cam in s.cameras.items():
        p = f"cameras.{name}"
        need(cam.name == name, f"{p}.name", f"must equal its key '{name}', got '{cam.name}'")
        need(cam.depth and cam.rgb, p, "needs rgb and depth enabled")
        need(cam.width >= 1 and cam.height >= 1, p,
             f"width and height must be >= 1, got {cam.width} x {cam.height}")
        need(np.isfinite(cam.fps) and cam.fps > 0, f"{p}.fps", f"must be > 0, got {cam.fps}")
        need(0 < cam.clipping_near < cam.clipping_far, p,
             f"needs 0 < clipping_near < clipping_far, got {cam.clipping_near}, "
             f"{cam.clipping_far}")
        need(0 < cam.z_near < cam.z_far, p,
             f"needs 0 < z_near < z_far, got {cam.z_near}, {cam.z_far}")
        fx, fy = cam.focal_x(), cam.focal_y()
        need(np.isfinite(fx) and np.isfinite(fy) and fx > 0 and fy > 0, f"{p}.focal",
             f"must be > 0, got {fx}, {fy}")
        need(_FiniteTransform(cam.X_PB), f"{p}.X_PB", "must be a finite pose")
    need(_FiniteTransform(s.robot.X_WB), "robot.X_WB", "must be a finite pose")

    ps = s.plant_scene
    need(ps.fruit.height_on_branch < ps.branch.length, "plant_scene.fruit.height_on_branch",
         f"{ps.fruit.height_on_branch} m puts the fruit above the branch top "
         f"(plant_scene.branch.length {ps.branch.length} m)")
    need(abs(ps.branch.bend) < ps.branch.length, "plant_scene.branch.bend",
         f"must be smaller than the branch length, got {ps.branch.bend}")
    need(float(np.linalg.norm(ps.pull.direction_W)) > 1e-9, "plant_scene.pull.direction_W",
         "must not be zero")
    from lmap_drake.plants.pepper import PepperShape
    fr = ps.fruit
    try:
        from lmap_drake.plants.pepper import PepperShapeOf
        PepperShapeOf(fr).validate()
    except ValueError as err:
        fail("plant_scene.fruit", f"is not a valid pepper shape: {err}")
    need(len(fr.peduncle_point) in (0, 3), "plant_scene.fruit.peduncle_point",
         f"must be empty or [x, y, z], got {list(fr.peduncle_point)}")
    need(not fr.peduncle_file or fr.mesh_file, "plant_scene.fruit.peduncle_file",
         "needs plant_scene.fruit.mesh_file (the procedural pepper has its own stalk)")
    if fr.mesh_file and ps.kind == "procedural":
        from lmap_drake.plants.fruit_mesh import FruitMeshError, LoadFruitMeshOf
        try:
            LoadFruitMeshOf(fr)
        except FruitMeshError as err:
            fail(err.key, err.detail)
    need(not fr.mesh_file or ps.kind == "procedural", "plant_scene.fruit.mesh_file",
         "needs plant_scene.kind: procedural (a multi-fruit plant takes a file per fruit: "
         "plant_scene.multi.fruits[i].fruit.mesh_file)")
    if ps.kind == "multi":
        from lmap_drake.plants.multi import ValidateMultiConfig
        from lmap_drake.plants.generator import PlantGenerationError
        try:
            ValidateMultiConfig(ps)
        except PlantGenerationError as err:
            fail(err.key, err.detail)
    need(s.shape.weights_file or s.shape.method == "supeps", "shape.weights_file",
         "is empty; the ssc and homa methods need the DeepSDF weights")
    isb = s.shape.init_scale_bounds
    need(len(isb) != 2 or isb[0] <= isb[1], "shape.init_scale_bounds",
         f"must be [lower, upper] with lower <= upper, got {list(isb)}")
    fv = s.shape.fruit_volume_cm3
    need(fv == 0 or 5 <= fv <= 3000, "shape.fruit_volume_cm3",
         f"must be 0 (the template's own size) or a pepper's volume in cm^3 (5-3000), "
         f"got {fv} (a value in m^3 or mm^3?)")
    from lmap_drake.station.hardware_config import ValidateHardwareConfig
    try:
        ValidateHardwareConfig(s.hardware)
    except ValueError as err:
        fail("hardware", str(err).replace("hardware config: ", ""))


def DumpScenario(s: Scenario, filename: str | Path) -> None:
    """Writes the resolved scenario (all fields) as YAML."""
    Path(filename).write_text(yaml_dump_typed(s, schema=Scenario))


def ScenarioWithCamera(scenario: Scenario, camera: dict, X_WC) -> Scenario:
    """``scenario`` with camera0's intrinsics and pose replaced (a recording,
    or the hardware camera)."""
    import copy
    from pydrake.common.schema import Transform
    from pydrake.math import RigidTransform
    from pydrake.systems.sensors import CameraConfig
    s = copy.deepcopy(scenario)
    cam = s.cameras["camera0"]
    cam.width, cam.height = int(camera["width"]), int(camera["height"])
    cam.focal = CameraConfig.FocalLength(x=float(camera["fx"]), y=float(camera["fy"]))
    cam.center_x, cam.center_y = float(camera["cx"]), float(camera["cy"])
    X = X_WC if isinstance(X_WC, RigidTransform) else RigidTransform(np.asarray(X_WC, float))
    cam.X_PB = Transform(X)
    cam.X_PB.base_frame = "world"
    return s
