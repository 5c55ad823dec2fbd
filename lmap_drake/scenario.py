"""Scenario configuration: the sections of every component, composed and
loaded with Drake's ``yaml_load_typed``.

A scenario file holds named scenarios at top level (``Defaults``,
``OneOfEverything``, ...), in the style of Drake's ``examples/hardware_sim``.
Unknown keys are errors; the message names the key path and the file. Each
section's dataclass and its validation live beside the component it
configures (``station/config.py``, ``plants/config.py``,
``perception/config.py``, ``shape/config.py``, ``deformation/config.py``,
``station/hardware_config.py``); this module composes them, loads, checks
the YAML itself (unknown keys, bad scalars, keys that moved) and dumps.

Units: metres, seconds, radians unless a field name says otherwise
(``*_deg``, ``*_cm``). Frames: ``W`` world, ``B`` robot base, ``C`` camera.
"""
import collections.abc
import copy
import dataclasses as dc
import re
import typing
from pathlib import Path

import numpy as np
import yaml
from pydrake.common.schema import Transform
from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed
from pydrake.geometry import LightParameter, SceneGraphConfig
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlantConfig
from pydrake.systems.analysis import SimulatorConfig
from pydrake.systems.sensors import CameraConfig

from lmap_drake.config_checks import CheckRules
from lmap_drake.deformation.config import DeformationConfig, ValidateDeformationConfig
from lmap_drake.errors import ConfigError, InputError
from lmap_drake.paths import DEFAULT_SCENARIO_FILE, DEFAULT_SCENARIO_NAME
from lmap_drake.perception.config import PerceptionConfig, ValidatePerceptionConfig
from lmap_drake.plants.config import PlantSceneConfig, ValidatePlantSceneConfig
from lmap_drake.shape.config import ShapeConfig, ValidateShapeConfig
from lmap_drake.station.config import (CameraNoiseConfig, DefaultCameraConfig, RobotConfig,
                                       ValidateCameraNoiseConfig, ValidateCameras,
                                       ValidateRobotConfig)
from lmap_drake.station.hardware_config import HardwareConfig, ValidateHardwareConfig


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
    verdicts are kept in its ``reason`` but do not stop it.

    ``speed_scale`` (0, 1] scales every arm motion of the episode (joint
    moves, approach, pull, release, retreat); on hardware the joint speed is
    also bounded by ``hardware.ur.joint_speed_limit``. ``release_and_retreat``
    ends the episode by opening the gripper and backing out to the start
    pose (false: the episode ends holding the leaf after the re-estimation).
    ``approach_speed`` (m/s): the TCP's mean speed on the final approach
    (pre-grasp -> grasp, open gripper) and on the way back out after the
    release; near a wrist singularity the joints (at most half their
    velocity limit) set a slower pace. Until 2026-11-26 the approach was timed
    by the joints alone at 0.15 of their limit: 5 cm took 0.42-0.74 s on
    the single-fruit suite's grasps (7-12 cm/s) but 4.4 s (1.1 cm/s) where
    the wrist turned 1.3 rad along it (``three_fruits_default``); 0.1 keeps
    the typical pace and ends the slow ones (0.05 made every single-fruit
    episode about 1 simulated second longer).
    ``return_speed_scale``: the held leaf is carried back to where it was
    grasped (before the release) this many times faster than it was moved
    (the pull's pace: 3 cm/s, turns at 0.5 rad/s).

    ``action_families``: 'pull' (the paper's straight pulls: ``distances``
    along the ``num_directions`` fixed directions) and 'arc' (ours: the
    grasped leaf swung about its estimated petiole attachment by each of
    ``arc_angles_deg`` about ``num_arc_axes`` axes perpendicular to the
    attachment-grasp line, the gripper turning with it; direction ids
    100 + axis) and 'twist' (ours: the gripper turns by each of
    ``twist_angles_deg``, both senses, about the attachment-grasp line, so
    the blade turns toward edge-on about it; direction ids 200, 201).
    ``force_action`` names an arc by its chord (m).
    ``continuation_families``: the families a re-plan from the held leaf
    may use (those also in ``action_families``). Pulls are left out by
    default: a straight pull from a leaf already turned is what overloaded
    the petiole among the planner's continuations (2 cm pulls after an
    arc, 2 of 12 past 15 N on random suites: 15.3 and 17.4 N), while the
    arcs and twists it chose there stayed below 13 N.
    ``continue_after_pull``: whether a straight pull may be followed by a
    further motion. Off by default: a pull loads the petiole along its
    axis and a turn after it compounds that load. In the multi-fruit
    plants, where the first motion is a pull more often, 3 of 4 reveals
    that turned the leaf after a pull reached 13.0-17.6 N on the petiole
    (a fifth ended its episode at 15.4 N), 9 single-motion reveals at most
    10.7 N; in the single-plant suites the first motion was a pull in none
    of 113 episodes.

    ``targets``: ``largest`` reveals the most-seen fruit (the paper's
    single-fruit episode); ``all`` reveals every fruit of the plant in turn
    (paper Sec. III-F): each fruit completed on its own, the least visible
    first, the leaf that hides it chosen among its occluding leaves by
    predicted visibility then energy; each target is planned, grasped,
    moved, observed, re-estimated, released and retreated from before the
    next (``planning.targets``, ``systems.planning.PlantPlanning``).

    ``ready_distances`` (m): the approach comes in along the gripper's axis
    from a ready pose this far behind the pre-grasp (itself
    ``pregrasp_distance`` behind the grasp); when the arm cannot reach a
    ready pose or would hit something on the way to the pre-grasp, the
    next distance is tried (the grasp and the last 5 cm of the approach
    stay the same; the action's record says which was used,
    ``ready_distance``). On the far side of a plant the 8 cm ready pose can
    lie beyond the UR5's reach: with the 2 cm fallback two fruits of the
    multi-fruit suite were revealed further (0.31 -> 0.79 and 0.67 -> 0.76);
    the single-fruit suite chose the same actions either way. [0.08] keeps
    the one distance.

    ``min_usable_grasps``: when fewer grasps than this pass the IK and robot
    checks (a small leaf near the branch, an edge the arm reaches
    awkwardly), the failed grasps are retried with the gripper turned 180
    deg about its approach axis and with the approach tilted +-35 and +-70
    deg in the blade's plane (70: nearly from the leaf's side), and grasps
    between half of ``min_branch_distance`` and it are tried too
    (``planning.lmap.GraspAlternatives``; the record's ``approach_tilt_deg``
    and ``gripper_turned`` say which was used; 0 = never). Still short,
    the grasp set is made again at each of ``deeper_grasp_insets`` (m
    inside the leaf's outline, in turn, until enough pass; grasp ids 100 +
    i, 200 + i; [] = never): on the crowded multi-fruit plants every grasp
    1 cm inside the rim could fail a robot check by a few millimetres.

    ``max_replans``: after the action and the re-estimation, while the
    fruit is predicted less than ``early_stop_fraction`` visible, plan a
    further motion from the held leaf (its deformation predicted from the
    leaf as now observed) up to this many times; each is executed, held and
    observed like the first. The leaf is carried back along all of them
    before it is released. A further motion must raise the predicted
    visibility by at least ``min_replan_gain`` (fraction of the fruit's
    voxels) over the leaf held where it is.

    ``hinge_bending_weight`` (m^2 per rad^2 per leaf node): the petiole's
    bending at its attachment, added to every action's predicted energy as
    weight * theta^2, theta the turn of the grasp point about the estimated
    attachment (``planning.lmap.PetioleBendingEnergy``; 0 = the ARAP energy
    alone, as in the paper). Chosen on two suite scenes with
    ``scripts/eval_hazard_prediction.py`` (it maximises the Spearman rank
    correlation of the predicted energy with the FEM petiole force over
    pulls and arcs together) and checked on two others.

    ``max_hinge_deg``: no action (with the motions before it) may turn the
    grasp more than this about the attachment. In the FEM world 45-degree
    arcs loaded the petiole up to 11 N on four suite scenes, while on random
    scenes 60-degree turns reached 15.1-15.3 N (the plant-hazard limit is
    15 N), so the arcs stop at 45 degrees and re-planning may add a little
    (see ``max_replan_turn_deg``).

    ``max_replan_turn_deg``: a re-plan from the held leaf may not bring the
    equivalent turn (from the first grasp) past this: 45, the largest arc.
    At ``max_hinge_deg`` (50) a re-plan could add a 30-degree twist to a
    45-degree arc (equivalent turn 47.4); on a random multi-fruit plant
    that loaded the petiole 16.2 N. Executed from the planner's own grasps
    on three such plants (``scripts/eval_hazard_prediction.py --then_twist
    30 --then_arc 15 30 --then_turn_band 45 50``), of the continuations
    into 45-50 degrees after 45-degree arcs that passed the leaf checks and
    stayed under 15 N, twists took the load past 15 N 12 times in 58 and
    arcs 4 times in 40 (the hinge estimate is 0.6-2 cm off there; the
    petiole's true turn after the arc was 36-80 degrees). On the
    single-fruit suite four such 15-degree arcs had stayed at 7.6-9.2 N and
    added 0.04-0.09 visibility.

    ``petiole_torsion_ratio``: a twist loads the petiole in torsion; the
    turn that the bending term and ``max_hinge_deg`` see is the equivalent
    sqrt(bend^2 + ratio twist^2) (``planning.lmap.EquivalentTurnDeg``), the
    ratio being the petiole's torsional to bending stiffness. 0.25 is the
    geometric mean of the bounds the FEM world gave on two random suites
    (seeds 157 and 211): 45-degree arcs followed by 30-degree twists loaded
    the petiole 7.3-11.7 N (12 episodes: allowed needs ratio <= 0.53), by
    60-degree twists 11.5-15.6 N (3: rejected needs ratio > 0.13).

    ``max_tether_elongation`` (m): no action (with the motions before it)
    may end the grasp farther than this beyond its starting distance from
    the estimated attachment (0 = no limit). The petiole is stiff along its
    axis: of 160 straight pulls executed in four suite scenes
    (``scripts/eval_hazard_prediction.py``), those lengthening that
    distance by more than 2 cm loaded the petiole past 15 N 33 times in 37,
    by 1.5-2 cm 4 in 12, by at most 1.5 cm 15 in 111 (arcs and twists keep
    it); two straight 8 cm lifts on multi-fruit plants loaded it 19.7 and
    23.6 N.

    ``max_pull_distance`` (m): the longest straight pull from a grasp 10 cm
    from the estimated attachment, scaled by (L / 10 cm)^2 for a grasp L
    from it (``planning.lmap.MaxPullDistance``; 0 = no cap; arcs are capped
    by ``arc_lever_reference``, twists are not). Like
    ``max_energy_per_node`` it vetoes after the scores are normalised over
    every action that passed the checks, so it does not re-rank the rest
    (removing the longer pulls first turned the single-fruit suite's 45°
    arcs into 30° ones: visibility 0.99 -> 0.95). The leaf acts as a beam
    clamped at its petiole: moving the grasp by d bends the petiole by a
    moment that grows as d / L^2. Measured on five random multi-fruit
    plants from the planner's own grasps (``scripts/eval_hazard_prediction.py``
    on ``make_suite.py --multi --random`` seeds 5151 and 5252; 380 pulls of
    1.5-4.5 cm): at a lever of 6.2-7 cm a 1.5 cm pull loaded the petiole
    13.8-14.8 N, at 10-12 cm 4-5 N. Of the 296 pulls that passed the energy,
    hinge and tether limits, 13 went past 15 N (up to 30.2 N); with this
    cap none of the 166 left did, the largest 11.9 N (3.5 cm: 14.9 N, where
    the attachment estimate was 3 cm off). On the single-fruit suite's four
    hazard scenes the same cap keeps 97 of 144 such pulls, the largest
    9.6 N.

    ``arc_lever_reference`` (m): an arc about the estimated attachment may
    turn at most 45 deg x L / this, L the grasp's distance to the
    attachment (``planning.lmap.MaxArcAngle``; 0 = no cap): turning the
    blade takes a moment at the petiole, and the grasp supplies it with a
    force that grows as the lever shortens. A veto after scoring, like the
    pull cap. Over 155 arcs that evaluations chose first (suites, random
    plants, pepper meshes not of the family), the 45 deg arcs from grasps
    under 7 cm from the attachment loaded the petiole past 15 N in 2 of 18
    (16.4 and 15.8 N), none of the 8 such 30 deg arcs did (at most 12.1 N),
    and 45 deg arcs from 9 cm or more stayed under 12.2 N. At 7.5 cm a 45
    deg arc needs L >= 7.5 cm, a 30 deg one 5 cm.

    ``robot_fruit_margin`` (m): every part of the robot but the two fingers
    (arm, wrist, the gripper's body and coupling) keeps this far from every
    estimated fruit; the fingers, which must reach a leaf lying on its
    fruit, keep ``collision_margin``. A fruit's estimate is seen on one
    side only, and its unseen side can be a centimetre off: in
    ``four_fruits`` the gripper's coupling ended an arc 5.8 mm from the
    estimate of a fully visible fruit and 5.1 mm inside the real one (237
    N on the fruit). Off (below ``collision_margin``) means the one margin.

    ``check_leaf_branch``: reject an action whose predicted leaf ends within
    ``collision_margin`` of the completed branch (stems and shoots) after
    moving toward it, as the paper's leaf-fruit check does for the fruit
    (leaf points resting that close, the petiole's base, are not counted).
    The deformation graph does not collide the leaf with the branch, while
    the FEM leaf is pressed against it and loads its own petiole. Off by
    default: on two random multi-fruit plants (seed 5151, 45 arcs and
    twists of 45-60 deg from the planner's grasps,
    ``scripts/eval_hazard_prediction.py``, column ``leaf_branch``) it
    caught none of the three motions that pressed the held leaf into the
    main stem (17-28 N) and rejected two harmless ones (4-9 N): the
    prediction and the completed stem are not yet accurate enough for it.

    ``max_reveals_per_fruit`` (``targets: all``): how many times one fruit
    may be revealed (2, the default; 1 is the paper's one leaf per fruit).
    A further reveal costs a grasp cycle; on the multi-fruit suite 2 gave
    16 / 18 fruits >= 0.9 over the fused views against 12 / 18 with 1, the
    same safety, and 3-fruit episodes of 70-76 s (two workers); see the
    README. A fruit under two leaves shows at most what
    one leaf alone hides while that leaf is moved; the other leaf's part is
    seen only when it is moved in turn (the views are fused, so the shape
    re-estimate sees both parts). A fruit is revealed again after every
    fruit's first reveal, and only if a leaf not moved yet alone hides at
    least ``next_leaf_min_gain`` (fraction of its surface) in the current
    view, the bar ``min_replan_gain`` sets for a further motion; that part
    was hidden in every earlier view too, since that leaf never moved. The
    leaf moved before is found in the current view by its points in the
    view its move was planned in (``planning.targets.SeparateMovedLeaves``;
    where the segmenter joined it to a touching blade, it is split off).
    ``reveal_moved_leaf_again``: when no leaf not moved yet hides that
    much, a leaf moved before may be moved again if it alone hides at
    least ``next_leaf_min_gain`` of the fruit's surface that no view has
    shown (marked by pixel, ``VisibilityModel.Observed``, from the fruit's
    points in the current view and in its re-estimates made while a leaf
    was held, ``systems.planning._ShownFruitPoints``); its actions then
    score by that surface (N_vis), and the reveal is made only if its
    chosen action shows at least ``next_leaf_min_gain`` of it."""
    num_grasps: int = 15
    grasp_inset: float = 0.01
    num_directions: int = 14
    max_branch_angle_deg: float = 120.0
    distances: list[float] = dc.field(default_factory=lambda: [0.02, 0.04, 0.06, 0.08])
    early_stop_fraction: float = 0.95
    pregrasp_distance: float = 0.05
    pregrasp_opening: float = 0.035
    ready_distances: list[float] = dc.field(default_factory=lambda: [0.08, 0.02])
    grasp_close_width: float = 0.0     # the closing ramp's end: fully closed, so the pads meet a real 0.2-0.5 mm leaf
    gripper_close_speed: float = 0.05
    grasp_attach_opening: float = 0.006
    min_branch_distance: float = 0.06
    min_usable_grasps: int = 3
    deeper_grasp_insets: list[float] = dc.field(default_factory=lambda: [0.02, 0.03])
    targets: str = "largest"   # largest | all
    visibility_voxel: float = 0.003
    collision_margin: float = 0.005
    robot_fruit_margin: float = 0.015
    energy_weight: float = 1.0
    max_energy_per_node: float = 5.9e-7
    force_action: list[float] = dc.field(default_factory=list)
    method: str = "lmap"  # lmap | random | upward | min_overlap
    speed_scale: float = 1.0
    approach_speed: float = 0.1
    return_speed_scale: float = 1.0
    release_and_retreat: bool = True
    action_families: list[str] = dc.field(default_factory=lambda: ["pull", "arc", "twist"])
    continuation_families: list[str] = dc.field(default_factory=lambda: ["arc", "twist"])
    continue_after_pull: bool = False
    arc_angles_deg: list[float] = dc.field(default_factory=lambda: [15.0, 30.0, 45.0])
    twist_angles_deg: list[float] = dc.field(default_factory=lambda: [30.0, 60.0])
    num_arc_axes: int = 8
    max_replans: int = 1
    min_replan_gain: float = 0.05
    hinge_bending_weight: float = 3.0e-7
    max_hinge_deg: float = 50.0
    max_replan_turn_deg: float = 45.0
    petiole_torsion_ratio: float = 0.25
    max_tether_elongation: float = 0.015
    max_pull_distance: float = 0.03
    arc_lever_reference: float = 0.075
    check_leaf_branch: bool = False
    max_reveals_per_fruit: int = 2
    next_leaf_min_gain: float = 0.05
    reveal_moved_leaf_again: bool = True


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


def RawYaml(text: str, where: str = "the YAML text"):
    """Plain-YAML parse that keeps Drake's tagged values (``!Rpy``) as maps.
    A duplicate key or malformed YAML raises ScenarioError naming ``where``
    (Drake's loader would silently keep the last duplicate)."""
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
        moved = [_MovedKeyMessage(b[len(root) + 1:] if root else b) for b in bad]
        if any(moved):
            return ScenarioError(f"{next(m for m in moved if m)} (in {where})")
        if bad:
            msg = (f"unknown key(s) {', '.join(bad)} in {where}; valid keys are the "
                   f"fields of the Scenario dataclasses (lmap_drake/scenario.py and the "
                   f"sections' config.py modules) "
                   f"(Drake said: {msg})")
            return ScenarioError(msg)
        bad = _bad_scalars(Scenario, raw, root)
        if bad:
            return ScenarioError(f"could not load scenario from {where}: bad value(s): "
                                 f"{'; '.join(bad)} (Drake said: {msg})")
    return ScenarioError(f"could not load scenario from {where}: {msg}")


def ReadScenarioFile(path: Path) -> str:
    """The text of a scenario file; ScenarioError when it cannot be read."""
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


# Keys that moved into a sub-section (old dotted path -> new one). YAML with
# an old key is rewritten to the new one before loading (same value); a key
# set both ways is an error, and an old key the rewrite cannot reach (under a
# YAML merge key) fails with a one-line message naming the new one.
MOVED_KEYS = {
    **{f"shape.{k}": f"shape.ssc.{k}" for k in (
        "w_sur", "w_neg", "w_ped", "w_reg", "w_neg_completed_branch", "learning_rate",
        "iterations", "num_peduncle_points", "loss_length_unit", "push_from_camera",
        "max_surface_points", "max_negative_points", "negative_margin",
        "max_negative_candidates", "peduncle_max_distance", "peduncle_cone_deg",
        "peduncle_huber", "peduncle_moves_scale", "peduncle_follow_axis", "peduncle_slide",
        "peduncle_base_distance", "init_from_observation", "fruit_volume_cm3",
        "rotation_lr_scale", "rotation_hold_steps", "w_rot", "init_scale_bounds",
        "refresh_every", "mesh_spacing", "reestimate_w_ped",
        "reestimate_w_neg_completed_branch", "reestimate_rotation_lr_scale",
        "reestimate_w_rot", "reestimate_rotation_hold_steps")},
    **{f"shape.branch_{k}": f"shape.branch.{k}" for k in (
        "slab", "radius_factor", "mesh_res", "match_distance")},
}


def _MovedKeyMessage(path: str) -> str:
    """'old is now new' for a moved key path (relative to the scenario), else ''."""
    new = MOVED_KEYS.get(re.sub(r"\[\d+\]", "", path))
    return f"{path} is now {new}" if new else ""


def _MoveKeys(scenario: yaml.Node, where: str) -> bool:
    """Moves the old keys of ``MOVED_KEYS`` in the composed scenario map to
    their new place (in place); True if any moved."""
    if not isinstance(scenario, yaml.MappingNode):
        return False
    moved = False
    for old, new in MOVED_KEYS.items():
        *old_parents, old_key = old.split(".")
        *new_parents, new_key = new.split(".")
        node = scenario
        for part in old_parents:
            node = next((v for k, v in node.value if k.value == part), None)
            if not isinstance(node, yaml.MappingNode):
                break
        else:
            item = next(((k, v) for k, v in node.value if k.value == old_key), None)
            if item is None:
                continue
            parent = scenario
            for part in new_parents:
                child = next((v for k, v in parent.value if k.value == part), None)
                if child is None:
                    child = yaml.MappingNode("tag:yaml.org,2002:map", [])
                    parent.value.append((yaml.ScalarNode("tag:yaml.org,2002:str", part),
                                         child))
                if not isinstance(child, yaml.MappingNode):
                    raise ScenarioError(f"{old} is now {new}, but {where} sets "
                                        f"{'.'.join(new_parents)} to a non-map")
                parent = child
            if any(k.value == new_key for k, _ in parent.value):
                raise ScenarioError(f"{old} is now {new}; {where} sets both")
            node.value.remove(item)
            parent.value.append((yaml.ScalarNode("tag:yaml.org,2002:str", new_key), item[1]))
            moved = True
    return moved


def MigrateScenarioText(text: str, where: str, named: bool, section: str = "") -> str:
    """``text`` with the keys that moved (``MOVED_KEYS``) written at their
    new place, in every scenario (``named``: a file of named scenarios) or in
    the one scenario (or the one ``section`` of a scenario, e.g. ``shape``);
    ``text`` itself when none moved or it is not YAML."""
    leaves = {old.rsplit(".", 1)[1] for old in MOVED_KEYS}
    if not any(leaf in text for leaf in leaves):
        return text
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return text  # RawYaml names the error
    if not isinstance(root, yaml.MappingNode):
        return text
    scenarios = [v for _, v in root.value] if named else [root]
    if section:
        scenarios = [yaml.MappingNode("tag:yaml.org,2002:map",
                                      [(yaml.ScalarNode("tag:yaml.org,2002:str", section), s)])
                     for s in scenarios]
    moved = False
    for scenario in scenarios:
        moved = _MoveKeys(scenario, where) or moved
    return yaml.serialize(root, Dumper=yaml.SafeDumper) if moved else text


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
        text = ReadScenarioFile(path)
        RawYaml(text, str(path))  # duplicate keys, bad YAML: named as written
        text = MigrateScenarioText(text, str(path), named=not bare)
        raw_all = RawYaml(text, str(path))
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
        RawYaml(text, "--scenario_text")
        text = MigrateScenarioText(text, "--scenario_text", named=False)
        raw = RawYaml(text, "--scenario_text")
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


# Value rules for Validate beyond each section's own (see
# ``lmap_drake.config_checks`` for the rule syntax): key path -> rule.
_RULES = {
    "random_seed": ">=0",
    "simulation_duration": ">0",
    "planner.num_grasps": ">=1",
    "planner.grasp_inset": ">=0",
    "planner.num_directions": "[1,14]",
    "planner.max_branch_angle_deg": "(0,180]",
    "planner.distances": "+x>0",
    "planner.early_stop_fraction": "(0,1]",
    "planner.pregrasp_distance": ">0",
    "planner.pregrasp_opening": "(0,0.085]",
    "planner.ready_distances": "+x>=0",
    "planner.grasp_close_width": "[0,0.085]",
    "planner.gripper_close_speed": ">0",
    "planner.grasp_attach_opening": "[0,0.085]",
    "planner.min_branch_distance": ">=0",
    "planner.min_usable_grasps": ">=0",
    "planner.petiole_torsion_ratio": ">=0",
    "planner.max_tether_elongation": ">=0",
    "planner.max_pull_distance": ">=0",
    "planner.arc_lever_reference": ">=0",
    "planner.visibility_voxel": ">0",
    "planner.collision_margin": ">=0",
    "planner.robot_fruit_margin": ">=0",
    "planner.energy_weight": ">=0",
    "planner.max_energy_per_node": ">=0",
    "planner.speed_scale": "(0,1]",
    "planner.approach_speed": ">0",
    "planner.return_speed_scale": ">0",
    "planner.arc_angles_deg": "+x>0",
    "planner.twist_angles_deg": "+x>0",
    "planner.num_arc_axes": ">=1",
    "planner.max_replans": ">=0",
    "planner.max_reveals_per_fruit": ">=1",
    "planner.next_leaf_min_gain": "[0,1]",
    "planner.min_replan_gain": "[0,1]",
    "planner.hinge_bending_weight": ">=0",
    "planner.max_hinge_deg": "(0,180]",
    "planner.max_replan_turn_deg": "(0,180]",
}
_ENUMS = {
    "planner.method": ("lmap", "random", "upward", "min_overlap"),
    "planner.targets": ("largest", "all"),
}


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


def Validate(s: Scenario, sources: typing.Sequence[tuple[dict, str]] = ()) -> None:
    """Checks values the type system cannot (list lengths, ranges,
    enumerations, finiteness, consistency) before anything is built: every
    section's own validation, then the checks across sections; raises
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

    try:
        CheckRules(s, "", _RULES, _ENUMS)   # every number of every section finite, too
        ValidateRobotConfig(s.robot, "robot")
        ValidateCameras(s.cameras, "cameras")
        ValidateCameraNoiseConfig(s.camera_noise, "camera_noise")
        ValidatePlantSceneConfig(s.plant_scene, "plant_scene")
        ValidatePerceptionConfig(s.perception, "perception")
        ValidateShapeConfig(s.shape, "shape")
        ValidateDeformationConfig(s.deformation, "deformation")
    except ConfigError as err:
        fail(err.key, err.detail)
    fams = list(s.planner.action_families)   # deformation.action.FAMILIES
    need(bool(fams) and all(f in ("pull", "arc", "twist") for f in fams)
         and len(set(fams)) == len(fams),
         "planner.action_families",
         f"must be a non-empty list of distinct families of 'pull', 'arc', 'twist', "
         f"got {fams}")
    cont = list(s.planner.continuation_families)
    need(all(f in ("pull", "arc", "twist") for f in cont) and len(set(cont)) == len(cont),
         "planner.continuation_families",
         f"must be a list of distinct families of 'pull', 'arc', 'twist', got {cont}")
    need(all(0 < a < 180 for a in s.planner.arc_angles_deg), "planner.arc_angles_deg",
         f"must be angles in (0, 180) degrees, got {list(s.planner.arc_angles_deg)}")
    need(all(0 < a < 180 for a in s.planner.twist_angles_deg), "planner.twist_angles_deg",
         f"must be angles in (0, 180) degrees, got {list(s.planner.twist_angles_deg)}")
    need(all(0 < d < 0.1 for d in s.planner.deeper_grasp_insets),
         "planner.deeper_grasp_insets",
         f"must be insets in (0, 0.1) m, got {list(s.planner.deeper_grasp_insets)}")
    fa = s.planner.force_action
    need(len(fa) in (0, 3) and (not fa or (float(fa[0]).is_integer() and
                                           float(fa[1]).is_integer() and fa[2] > 0)),
         "planner.force_action", "must be empty or [grasp_id, direction_id, distance m], "
         f"got {list(fa)}")
    need(not fa or s.planner.method == "lmap", "planner.force_action",
         "picks an LMAP candidate: it needs planner.method 'lmap'")
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
    s = copy.deepcopy(scenario)
    cam = s.cameras["camera0"]
    cam.width, cam.height = int(camera["width"]), int(camera["height"])
    cam.focal = CameraConfig.FocalLength(x=float(camera["fx"]), y=float(camera["fy"]))
    cam.center_x, cam.center_y = float(camera["cx"]), float(camera["cy"])
    X = X_WC if isinstance(X_WC, RigidTransform) else RigidTransform(np.asarray(X_WC, float))
    cam.X_PB = Transform(X)
    cam.X_PB.base_frame = "world"
    return s
