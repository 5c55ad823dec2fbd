"""Configuration of the plant world: the procedural plant (branch, pepper,
FEM leaf), the multi-fruit plant, the rigid placeholder, the scripted pull
and the ground-truth outcome thresholds. The ``plant_scene`` section of the
scenario. World frame W, metres."""
# (no ``from __future__ import annotations``: Drake's ``yaml_load_typed``
# reads the field types)

import dataclasses as dc

import numpy as np
from pydrake.geometry import Rgba
from pydrake.math import RigidTransform, RollPitchYaw

from lmap_drake.config_checks import CheckRules, Need
from lmap_drake.errors import ConfigError
from lmap_drake.plants.fruit_mesh import FruitMeshError, LoadFruitMeshOf
from lmap_drake.plants.generator import PlantGenerationError
from lmap_drake.plants.greenhouse_model import ValidateGreenhouseConfig
from lmap_drake.plants.mesh_plant_files import ValidateMeshPlant
from lmap_drake.plants.multi import ValidateMultiConfig
from lmap_drake.plants.pepper import PepperShapeOf


@dc.dataclass
class BranchConfig:
    """Rigid branch: a vertical cylinder, optionally bowed sideways (m)."""
    radius: float = 0.006  # m, cylinder radius
    length: float = 0.5  # m, height from the base ``plant_scene.p_W_branch_base`` to the top
    # m, sideways bow at mid-height (sine profile; 0 = straight): procedural, away
    # from the fruit's side (``fruit_side``); multi, toward camera0's right
    bend: float = 0.0
    # RGBA (0-1) of the branch, the side shoots and the peduncle stalks
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
    length: float = 0.13  # m, blade length along the midrib (petiole not included)
    width: float = 0.075  # m, blade width at its widest
    shape: str = "ovate"  # blade outline: ovate (widest near the base) | elliptic (in the middle)
    petiole_length: float = 0.04  # m, the stalk from the branch to the blade base
    petiole_width: float = 0.006  # m
    thickness: float = 0.002  # m, simulated blade thickness (two tet layers)
    target_tets: int = 1000  # about this many FEM tetrahedra (sizes the elements if element_size 0)
    element_size: float = 0.0  # 0 = derived from target_tets
    youngs_modulus: float = 10.0e6  # Pa, FEM material stiffness E
    poissons_ratio: float = 0.3  # FEM material Poisson ratio, [0, 0.5)
    mass_density: float = 100.0
    stiffness_damping: float = 0.01
    mass_damping: float = 1.0
    clearance: float = 0.025
    # m: at rest every leaf vertex keeps this far from the fruit surface (the
    # blade is pushed forward until it does); multi: from every fruit
    min_fruit_clearance: float = 0.004
    attach_above_fruit: float = 0.012
    bend_radius: float = 0.025
    color: Rgba = dc.field(default_factory=lambda: Rgba(0.2, 0.55, 0.15, 1.0))  # RGBA (0-1)


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
    variant: str = "blocky"  # a label (blocky | elongated | conical); the keys below shape it
    # [x, y, z] (m), the body's full extent before lobes and taper; z along the peduncle axis
    size: list[float] = dc.field(default_factory=lambda: [0.075, 0.075, 0.085])
    lobes: int = 4  # number of lengthwise furrows around the body; 0 = none
    lobe_depth: float = 0.08  # relative depth of the furrows, [0, 0.5)
    squareness: float = 2.4  # superquadric exponent of the body: 2 = ellipsoid, larger = boxier
    shoulder: float = 0.12  # relative flattening of the top around the peduncle, [0, 0.5)
    taper: float = 0.06  # relative narrowing of the blossom end, [0, 0.5); 0 = none
    cone: float = 0.0  # narrowing of the lower half in x-y, [0, 0.8): 0 = none, 0.45 = conical
    lobe_phase_deg: float = 0.0  # deg, turn of the lobes about the fruit's axis
    dimple: float = 0.0
    cavity_offset_deg: float = 0.0
    cavity_phase_deg: float = 0.0
    bend: float = 0.0
    bend_phase_deg: float = 0.0
    peduncle_curved: bool = False
    peduncle_angle_deg: float = 0.0
    peduncle_azimuth_deg: float = 0.0
    color: Rgba = dc.field(default_factory=lambda: Rgba(0.75, 0.05, 0.05, 1.0))  # RGBA (0-1)
    # RGBA (0-1) of the stripes (used with ``stripes`` > 0)
    stripe_color: Rgba = dc.field(default_factory=lambda: Rgba(0.55, 0.02, 0.02, 1.0))
    stripes: int = 0  # number of lengthwise stripes in ``stripe_color``; 0 = none
    height_on_branch: float = 0.22
    gap_to_branch: float = 0.004
    tilt_deg: float = 10.0
    tilt_azimuth_deg: float = 30.0
    lean_deg: float = 0.0
    peduncle_length: float = 0.015
    peduncle_radius: float = 0.004  # m, radius of the peduncle stalk (straight or curved)
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
    # Not read: ``lmap-drake run --scripted`` runs the pull; kept so older scenario files load.
    enabled: bool = True
    grasp_from_tip: float = 0.015
    grasp_v: float = 0.0
    pregrasp_distance: float = 0.05  # m, pre-grasp pose this far back along the approach axis
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
    sample_period: float = 0.05  # s of simulated time between two samples of these measures


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
    shoot_radius: float = 0.004  # m, radius of the fruits' side shoots, (0, 0.02]
    leaf_gap: float = 0.003
    free_leaf_swing_deg: float = 55.0
    leaf_leaf_contact: bool = False


@dc.dataclass
class GreenhouseFruitConfig:
    """A placed fruit of a greenhouse plant (``plant_scene.greenhouse.fruits``).
    It hangs on a short shoot and a curved stalk from stem ``stem`` at
    ``height`` (fraction of ``greenhouse.stem_length``), in the horizontal
    direction ``azimuth_deg`` from the stem (0: toward camera0, +90: camera0's
    right, 180: behind the stem). ``color``: red | yellow | orange | green |
    immature ("" = drawn from the seed). ``cover_leaves`` (0-2) leaves hang
    from its stalk in front of it, swung to hide ``occlusion`` of it from
    camera0 (nearest a grid of swings). ``target``: its occluders and the
    leaves near it are FEM (the arm may move them)."""
    stem: int = 0
    height: float = 0.35
    azimuth_deg: float = -70.0
    color: str = ""
    cover_leaves: int = 1
    occlusion: float = 0.7
    target: bool = True


@dc.dataclass
class GreenhouseConfig:
    """``plant_scene.kind: greenhouse``: a procedural greenhouse sweet-pepper
    plant (``lmap_drake/plants/greenhouse.py``), deterministic in ``seed``.
    ``num_stems`` (1-3) main stems of ``stem_length`` (m) from
    ``plant_scene.p_W_branch_base``, ``stem_spacing`` apart, leaning up to
    ``lean_deg`` and tied to strings; ``num_leaves`` (15-60) alternating
    leaves at the stems' nodes (blade length in ``leaf_length`` m, width /
    length in ``leaf_aspect``: lanceolate 0.3 .. ovate 0.7, drooping
    ``droop_deg``, cupped by ``curl``), the fruits' cover leaves included;
    the placed ``fruits`` and ``num_random_fruits`` more (not targets) at
    random nodes. FEM: the leaves hiding a target fruit from camera0, then
    those hiding the other fruits, then those within ``fem_radius`` (m) of
    a target, at most ``max_fem_leaves``; with ``fem_occluders`` that
    budget is raised to every leaf hiding any part of a fruit (up to 16: in a real plant
    every leaf a planner may grasp moves) (each
    about ``fem_target_tets`` tetrahedra, material from ``plant_scene.leaf``);
    every other leaf is static (welded, visual; with collision geometry if
    ``static_leaf_collision``; off: a welded leaf would stop the arm like a
    wall), each leaf green varied by ``leaf_color_variation`` (0-1), with a
    paler lower side. ``dressing``: strings, heating pipes, rails,
    slab; ``neighbour_row``: a static row of plants behind. ``textures``:
    every leaf (FEM and static) rendered with its own procedural texture
    (``lmap_drake/plants/leaf_texture.py``: base-to-tip colour gradient,
    lighter midrib and lateral veins, mottling, a greyer, darker lower side,
    a painted gloss band), deterministic in ``seed`` and the leaf's index,
    and every fruit with streaks, darker shoulders and a gloss band; false:
    flat colours (upper and lower side). Labels are the same either way."""
    seed: int = 0
    num_stems: int = 2
    stem_length: float = 0.75
    stem_spacing: float = 0.09
    lean_deg: float = 6.0
    num_leaves: int = 30
    leaf_length: list[float] = dc.field(default_factory=lambda: [0.07, 0.15])
    leaf_aspect: list[float] = dc.field(default_factory=lambda: [0.35, 0.65])
    droop_deg: list[float] = dc.field(default_factory=lambda: [20.0, 60.0])
    curl: float = 0.25
    fruits: list[GreenhouseFruitConfig] = dc.field(
        default_factory=lambda: [GreenhouseFruitConfig()])
    num_random_fruits: int = 2
    fem_radius: float = 0.06
    max_fem_leaves: int = 3
    fem_occluders: bool = True
    fem_target_tets: int = 500
    static_leaf_collision: bool = False
    leaf_color_variation: float = 0.2
    dressing: bool = True
    neighbour_row: bool = True
    textures: bool = True


@dc.dataclass
class PlantPose:
    """A pose in W: ``translation`` (m), then turned by ``rpy_deg`` (roll,
    pitch, yaw in degrees, about the fixed axes x, y, z in turn)."""
    translation: list[float] = dc.field(default_factory=lambda: [0.5, 0.0, 0.1])
    rpy_deg: list[float] = dc.field(default_factory=lambda: [0.0, 0.0, 0.0])

    def GetRigidTransform(self) -> RigidTransform:
        return RigidTransform(RollPitchYaw(np.deg2rad(self.rpy_deg)), self.translation)


@dc.dataclass
class MeshPlantConfig:
    """``plant_scene.kind: mesh_plant``: a plant made of mesh files (OBJ,
    PLY, STL, glTF, GLB; ``lmap_drake/plants/mesh_plant_files.py``, format
    in docs/how-to/bring-your-own-plant.md). Exactly one of: ``folder``
    (``stems/ leaves/ fruits/`` subfolders, or a ``plant.yaml`` manifest
    in it, which then lists the parts), ``manifest`` (a manifest YAML; its
    file paths relative to it) or ``file`` (one glTF / OBJ whose parts are
    named ``stem*`` / ``leaf*`` / ``fruit*``). Relative paths: from the
    current directory, then the repository root. ``scale``: metres per file
    unit (0.001 for millimetres; times the manifest's ``scale``);
    ``up_axis``: y | z | auto (y for glTF / GLB, z otherwise). ``X_W_plant``:
    the pose of the files' frame in W (default: its origin at [0.5, 0, 0.1],
    the default ``p_W_branch_base``). ``targets``: fruit names (file stem or
    part name) that are targets; empty: the manifest's ``target: true``
    fruits, else every fruit. FEM: the leaves hiding a target from camera0
    (most first), then those within ``fem_radius`` (m) of one, at most
    ``max_fem_leaves``, become thin tetrahedral slabs (about
    ``fem_target_tets`` tets, thickness and material from
    ``plant_scene.leaf``) fixed at the petiole end nearest a stem; every
    other leaf is welded (visual, textured where given; collision only
    with ``static_leaf_collision``). A textured leaf card is cut to its
    texture's alpha outline (alpha below ``alpha_threshold`` is outside).
    ``fruit_color`` / ``plant_scene.leaf.color`` / ``plant_scene.branch.color``
    colour parts without colour or texture; ``dressing``: the greenhouse
    dressing (pipes, slab, glass) around the plant."""
    # the plant folder: stems/ leaves/ fruits/ subfolders, or a plant.yaml manifest in it
    folder: str = ""
    manifest: str = ""  # a manifest YAML listing the files and their part types
    file: str = ""  # one glTF / GLB / OBJ whose parts are named stem* / leaf* / fruit*
    scale: float = 1.0  # metres per file unit (0.001: millimetres), times the manifest's scale
    up_axis: str = "auto"  # the files' up axis: z | y | auto (y for glTF / GLB, else z)
    # the pose of the files' frame in W; default: its origin at the default p_W_branch_base
    X_W_plant: PlantPose = dc.field(default_factory=PlantPose)
    # target fruits by name (file stem / part name); empty: the manifest's, else all
    targets: list[str] = dc.field(default_factory=list)
    max_fem_leaves: int = 3  # at most this many leaves become FEM (0-8)
    fem_radius: float = 0.06  # m: a leaf this near a target fruit may become FEM
    fem_target_tets: int = 500  # about this many tetrahedra per FEM leaf (100-5000)
    alpha_threshold: float = 0.5  # a card texture's alpha below this is outside the leaf
    static_leaf_collision: bool = False  # welded leaves get collision geometry
    # RGBA (0-1) of a fruit without colour or texture in its file or the manifest
    fruit_color: Rgba = dc.field(default_factory=lambda: Rgba(0.75, 0.05, 0.05, 1.0))
    dressing: bool = False  # the greenhouse dressing (slab, pipes, glass) around the plant


@dc.dataclass
class PlantSceneConfig:
    """The plant in front of the robot. ``kind: procedural`` builds the
    branch, pepper and FEM leaf from the sub-configs, with the leaf swung so
    that it hides ``occlusion`` of the fruit from camera0; ``kind:
    placeholder`` is a cheap rigid scene (branch cylinder, leaf plate,
    pepper mesh) for fast tests; ``kind: multi`` a plant with several fruits
    on side shoots and several FEM leaves (``multi``,
    ``lmap_drake/plants/multi.py``); ``kind: greenhouse`` a dense greenhouse
    pepper plant (``greenhouse``, ``lmap_drake/plants/greenhouse.py``);
    ``kind: mesh_plant`` a plant from mesh files (``mesh_plant``). World
    frame, metres.

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
    name: str = ""  # the scene's name in episode records (``scenario``); empty = "default"
    # [x, y, z] (m, W): the branch's (main stem's) base; the placeholder's branch too
    p_W_branch_base: list[float] = dc.field(default_factory=lambda: [0.5, 0.0, 0.1])
    occlusion: float = 0.85
    # Side of the branch the fruit hangs on (sign only): +1 = camera0's right, -1 = its left
    fruit_side: float = -1.0
    branch: BranchConfig = dc.field(default_factory=BranchConfig)
    leaf: LeafConfig = dc.field(default_factory=LeafConfig)
    fruit: FruitConfig = dc.field(default_factory=FruitConfig)
    pull: ScriptedPullConfig = dc.field(default_factory=ScriptedPullConfig)
    outcome: OutcomeConfig = dc.field(default_factory=OutcomeConfig)
    multi: MultiPlantConfig = dc.field(default_factory=MultiPlantConfig)
    greenhouse: GreenhouseConfig = dc.field(default_factory=GreenhouseConfig)
    mesh_plant: MeshPlantConfig = dc.field(default_factory=MeshPlantConfig)
    sleep_distance: float = 0.03
    sleep_speed: float = 0.002
    fem_threads: int = 0
    # --- kind: placeholder only (rigid shapes welded to the world) ---

    branch_length: float = 0.5  # m, placeholder: branch cylinder height above p_W_branch_base
    branch_radius: float = 0.006  # m, placeholder: branch cylinder radius
    # [x, y, z] (m, W), placeholder: the lobed pepper mesh's centre
    fruit_center_W: list[float] = dc.field(default_factory=lambda: [0.5, -0.045, 0.33])
    # [x, y, z] (m), placeholder: the pepper's full extent (W axes)
    fruit_size: list[float] = dc.field(default_factory=lambda: [0.075, 0.075, 0.085])
    fruit_lobes: int = 4  # placeholder: the pepper's number of lobes; 0 = none
    # RGBA (0-1), placeholder: the pepper
    fruit_color: Rgba = dc.field(default_factory=lambda: Rgba(0.75, 0.05, 0.05, 1.0))
    # [x, y, z] (m, W), placeholder: the leaf plate's centre
    leaf_center_W: list[float] = dc.field(default_factory=lambda: [0.5, -0.1, 0.355])
    # [x, y, z] (m), placeholder: the leaf plate's box size along the W axes (y: thickness)
    leaf_size: list[float] = dc.field(default_factory=lambda: [0.10, 0.002, 0.065])
    # RGBA (0-1), placeholder: the leaf plate
    leaf_color: Rgba = dc.field(default_factory=lambda: Rgba(0.2, 0.55, 0.15, 1.0))
    # RGBA (0-1), placeholder: the branch cylinder
    branch_color: Rgba = dc.field(default_factory=lambda: Rgba(0.35, 0.5, 0.2, 1.0))



_RULES = {
    "p_W_branch_base": "3xfinite",
    "occlusion": "(0,1)",
    "branch.radius": ">0",
    "branch.length": ">0",
    "leaf.length": "[0.06,0.16]",
    "leaf.width": ">0",
    "leaf.petiole_length": ">0",
    "leaf.petiole_width": ">0",
    "leaf.thickness": ">0",
    "leaf.target_tets": "[100,20000]",
    "leaf.element_size": ">=0",
    "leaf.youngs_modulus": ">0",
    "leaf.poissons_ratio": "[0,0.5)",
    "leaf.mass_density": ">0",
    "leaf.stiffness_damping": ">=0",
    "leaf.mass_damping": ">=0",
    "leaf.clearance": ">=0",
    "leaf.min_fruit_clearance": ">=0",
    "leaf.attach_above_fruit": ">=0",
    "leaf.bend_radius": ">0",
    "fruit.size": "3x>0",
    "fruit.lobes": ">=0",
    "fruit.stripes": ">=0",
    "fruit.height_on_branch": ">0",
    "fruit.gap_to_branch": ">=0",
    "fruit.peduncle_length": ">0",
    "fruit.peduncle_radius": ">0",
    "fruit.mesh_scale": ">0",
    "pull.pregrasp_distance": ">0",
    "pull.pregrasp_opening": "(0,0.085]",
    "pull.direction_W": "3xfinite",
    "pull.distance": ">0",
    "pull.duration": ">0",
    "pull.hold": ">=0",
    "outcome.tear_stretch": ">0",
    "outcome.strain_percentile": "(0,100]",
    "outcome.petiole_max_force": ">0",
    "outcome.fruit_penetration": ">=0",
    "outcome.fruit_contact_force": ">=0",
    "outcome.sample_period": ">0",
    "mesh_plant.scale": ">0",
    "mesh_plant.X_W_plant.translation": "3xfinite",
    "mesh_plant.X_W_plant.rpy_deg": "3xfinite",
    "mesh_plant.max_fem_leaves": "[0,8]",
    "mesh_plant.fem_radius": "[0,0.3]",
    "mesh_plant.fem_target_tets": "[100,5000]",
    "mesh_plant.alpha_threshold": "(0,1)",
    "sleep_distance": ">=0",
    "sleep_speed": ">=0",
    "fem_threads": ">=0",
    "branch_length": ">0",
    "branch_radius": ">0",
    "fruit_center_W": "3xfinite",
    "fruit_size": "3x>0",
    "fruit_lobes": ">=0",
    "leaf_center_W": "3xfinite",
    "leaf_size": "3x>0",
}
_ENUMS = {
    "kind": ("placeholder", "procedural", "multi", "greenhouse", "mesh_plant"),
    "mesh_plant.up_axis": ("auto", "y", "z"),
    "leaf.shape": ("ovate", "elliptic"),
    "fruit.variant": ("blocky", "elongated", "conical"),  # plants.pepper.VARIANTS
}


def ValidatePlantSceneConfig(ps: PlantSceneConfig, path: str = "plant_scene") -> None:
    """Value rules, then the plant's consistency: the fruit below the branch
    top, a valid pepper shape, a loadable fruit mesh, a multi-fruit layout
    that fits (``plants.multi.ValidateMultiConfig``). Raises
    ``ConfigError`` (key path, what is wrong)."""
    CheckRules(ps, path, _RULES, _ENUMS)
    Need(ps.fruit.height_on_branch < ps.branch.length, f"{path}.fruit.height_on_branch",
         f"{ps.fruit.height_on_branch} m puts the fruit above the branch top "
         f"({path}.branch.length {ps.branch.length} m)")
    Need(abs(ps.branch.bend) < ps.branch.length, f"{path}.branch.bend",
         f"must be smaller than the branch length, got {ps.branch.bend}")
    Need(float(np.linalg.norm(ps.pull.direction_W)) > 1e-9, f"{path}.pull.direction_W",
         "must not be zero")
    fr = ps.fruit
    try:
        PepperShapeOf(fr).validate()
    except ValueError as err:
        raise ConfigError(f"{path}.fruit", f"is not a valid pepper shape: {err}") from None
    Need(len(fr.peduncle_point) in (0, 3), f"{path}.fruit.peduncle_point",
         f"must be empty or [x, y, z], got {list(fr.peduncle_point)}")
    Need(not fr.peduncle_file or fr.mesh_file, f"{path}.fruit.peduncle_file",
         f"needs {path}.fruit.mesh_file (the procedural pepper has its own stalk)")
    if fr.mesh_file and ps.kind == "procedural":
        try:
            LoadFruitMeshOf(fr)
        except FruitMeshError as err:
            raise ConfigError(err.key, err.detail) from None
    Need(not fr.mesh_file or ps.kind == "procedural", f"{path}.fruit.mesh_file",
         f"needs {path}.kind: procedural (a multi-fruit plant takes a file per fruit: "
         f"{path}.multi.fruits[i].fruit.mesh_file)")
    if ps.kind in ("multi", "greenhouse", "mesh_plant"):
        check = {"multi": ValidateMultiConfig, "greenhouse": ValidateGreenhouseConfig,
                 "mesh_plant": ValidateMeshPlant}[ps.kind]
        try:
            check(ps)
        except PlantGenerationError as err:
            raise ConfigError(err.key, err.detail) from None
