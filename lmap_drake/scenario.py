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
from pydrake.geometry import LightParameter, Rgba, SceneGraphConfig
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlantConfig
from pydrake.systems.analysis import SimulatorConfig
from pydrake.systems.sensors import CameraConfig

from lmap_drake.config_checks import CheckRules
from lmap_drake.deformation.config import DeformationConfig, ValidateDeformationConfig
from lmap_drake.errors import ConfigError, InputError
from lmap_drake.limits import MAX_SCENARIO_BYTES, CheckYamlLimits, ReadBounded, TooLargeError
from lmap_drake.paths import DEFAULT_SCENARIO_FILE, DEFAULT_SCENARIO_NAME
from lmap_drake.perception.config import PerceptionConfig, ValidatePerceptionConfig
from lmap_drake.planning.config import PlannerConfig, ValidatePlannerConfig
from lmap_drake.plants.config import PlantSceneConfig, ValidatePlantSceneConfig
from lmap_drake.shape.config import ShapeConfig, ValidateShapeConfig
from lmap_drake.station.config import (CameraNoiseConfig, DefaultCameraConfig, RobotConfig,
                                       ValidateCameraNoiseConfig, ValidateCameras,
                                       ValidateDrakeConfigs, ValidateRobotConfig)
from lmap_drake.station.hardware_config import HardwareConfig, ValidateHardwareConfig


@dc.dataclass
class Scenario:
    """Everything one run needs. See ``diagrams/default.yaml``."""
    # Seed of the run's randomness: the Random baseline's draws and, plus
    # ``camera_noise.seed_offset``, the simulated camera noise.
    random_seed: int = 0
    # s: how long ``lmap-drake run`` simulates a station snapshot (``kind:
    # placeholder``: the arm held at ``robot.initial_q``); episodes run until done.
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
    if schema is Rgba and data is not None:      # Drake's message names no key
        rgba = data.get("rgba") if isinstance(data, dict) else None
        ok = (isinstance(rgba, list) and len(rgba) in (3, 4) and all(
            isinstance(c, (int, float)) and not isinstance(c, bool) and 0 <= c <= 1
            for c in rgba))
        return [] if ok else [f"{path} = {data!r} (expected {{rgba: [r, g, b, a]}}, each "
                              f"in [0, 1])"]
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
        CheckYamlLimits(text, where)     # size, depth, alias expansion, huge integers
        return yaml.load(text, Loader=_Loader)
    except TooLargeError as err:
        raise ScenarioError(str(err)) from None
    except yaml.YAMLError as err:
        detail = " ".join(str(err).replace('in "<unicode string>", ', "").split())
        raise ScenarioError(f"{where} is not valid YAML: {detail}") from None


def ScenarioNames(path) -> list[str]:
    """The scenario names of the scenario file ``path`` (its top-level keys,
    those starting with '_' left out), in file order."""
    return [k for k in (RawYaml(Path(path).read_text(), str(path)) or {})
            if not str(k).startswith("_")]


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
        return ReadBounded(path, MAX_SCENARIO_BYTES, "scenario file").decode("utf-8")
    except TooLargeError as err:
        raise ScenarioError(f"{err} (lmap_drake.limits.MAX_SCENARIO_BYTES)") from None
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
        raw_all = RawYaml(text, str(path))  # duplicate keys, bad YAML: named as written
        migrated = MigrateScenarioText(text, str(path), named=not bare)
        if migrated is not text:
            text, raw_all = migrated, RawYaml(migrated, str(path))
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
        raw = RawYaml(text, "--scenario_text")
        migrated = MigrateScenarioText(text, "--scenario_text", named=False)
        if migrated is not text:
            text, raw = migrated, RawYaml(migrated, "--scenario_text")
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
}
_ENUMS: dict = {}


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
        ValidateDrakeConfigs(s.simulator_config, s.plant_config, s.scene_graph_config,
                             s.lights)
        ValidateCameraNoiseConfig(s.camera_noise, "camera_noise")
        ValidatePlantSceneConfig(s.plant_scene, "plant_scene")
        ValidatePerceptionConfig(s.perception, "perception")
        ValidateShapeConfig(s.shape, "shape")
        ValidateDeformationConfig(s.deformation, "deformation")
        ValidatePlannerConfig(s.planner, "planner")
    except ConfigError as err:
        fail(err.key, err.detail)
    try:
        ValidateHardwareConfig(s.hardware)
    except ValueError as err:
        fail(*("hardware." + str(err).replace("hardware config: ", "")).split(" ", 1))


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
