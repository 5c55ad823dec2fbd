"""Configuration of the station: the robot (UR5 + Robotiq 2F-85), the
simulated cameras (``DefaultCameraConfig``, the L515-like intrinsics) and
their sensor model (``CameraNoiseConfig``); the hardware's own settings are
in ``lmap_drake.station.hardware_config``. Sections ``robot``, ``cameras``
and ``camera_noise`` of the scenario. Frames: ``W`` world, ``B`` robot
base, ``P`` a camera's parent frame."""
# (no ``from __future__ import annotations``: Drake's ``yaml_load_typed``
# reads the field types)

import dataclasses as dc
import typing

import numpy as np
from pydrake.common.schema import Rotation, Transform
from pydrake.geometry import Rgba
from pydrake.math import RollPitchYaw
from pydrake.systems.sensors import CameraConfig

from lmap_drake.config_checks import CheckRules, CheckTransform, FiniteTransform, Join, Need, RuleError
from lmap_drake.limits import MAX_IMAGE_SIDE


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
    # Pose of the UR5 base frame B (the DH base, the UR controller's "Base")
    # in world W; also turns a ``robot_base`` camera calibration into world.
    X_WB: Transform = dc.field(
        default_factory=lambda: _transform([0.0, 0.0, 0.0], [0.0, 0.0, 180.0]))
    # Start joint angles (rad), shoulder_pan .. wrist_3, of the simulated arm
    # (a snapshot holds them); on hardware the arm starts where it stands.
    initial_q: list[float] = dc.field(
        default_factory=lambda: [-1.3941, -0.552, 1.9769, 0.1742, -1.4152, -0.1795])
    initial_gripper_width: float = 0.085  # m, simulated start opening of the pads (0 .. 0.085)
    # Joint PD stiffness of the simulated arm servo (N m/rad), one per joint
    # (Drake's implicit PD on the plant's actuators); unused on hardware.
    kp: list[float] = dc.field(default_factory=lambda: [8000., 8000., 4000., 600., 600., 300.])
    # Joint PD damping of the simulated arm servo (N m s/rad), one per joint.
    kd: list[float] = dc.field(default_factory=lambda: [400., 400., 200., 30., 30., 12.])
    gripper_kp: float = 4000.0  # N/m, PD stiffness of each simulated finger (prismatic joint)
    gripper_kd: float = 40.0  # N s/m, PD damping of each simulated finger
    # Add the arm's gravity torques (arm + gripper) to the simulated actuation,
    # as the UR controller does; false leaves the PD to hold the weight.
    gravity_compensation: bool = True



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
    depth_sigma_0: float = 0.001  # m, depth noise sigma's constant part: sigma = this + z2 z^2
    depth_sigma_z2: float = 0.002  # 1/m, depth noise sigma's part growing with depth z squared
    # weight a of the smooth part of the depth noise: sqrt(1 - a^2) white + a smooth; 0 = white only
    correlated_fraction: float = 0.5
    correlated_length_px: float = 6.0  # px, Gaussian width of the smooth depth noise; 0 = off
    grazing_start_deg: float = 72.0  # deg (ray to surface normal): returns start to drop out here
    grazing_full_deg: float = 86.0  # deg: every return is lost from here (linear in between)
    thin_width_px: float = 3.0  # px: surfaces narrower than this count as thin
    thin_dropout: float = 0.5  # probability that a thin surface's pixel has no return; 0 = off
    edge_jump: float = 0.01  # m: a larger depth difference between neighbours is a depth edge
    mixed_pixel_fraction: float = 0.3  # chance a depth-edge pixel becomes a flying pixel; 0 = off
    speckle_dropout: float = 0.002  # probability of a missing return anywhere; 0 = off
    depth_unit: float = 0.00025  # m, depth quantisation step; 0 = none
    exposure_variation: float = 0.15  # colour gain drawn per scene in 1 +- this
    white_balance_variation: float = 0.05  # per-channel colour gain drawn per scene in 1 +- this
    illumination_gradient: float = 0.12  # brightness ramp across the image, +- this, per scene
    read_noise: float = 1.5  # colour noise floor (sigma, 0-255 levels) added in quadrature
    shot_noise: float = 0.15  # colour shot noise: sigma^2 += shot_noise^2 I (I: 0-255 level)
    seed_offset: int = 0



_ROBOT_RULES = {
    "initial_q": "6xfinite",
    "kp": "6x>=0",
    "kd": "6x>=0",
    "initial_gripper_width": "[0,0.085]",
    "gripper_kp": ">=0",
    "gripper_kd": ">=0",
}
_CAMERA_NOISE_RULES = {
    "depth_sigma_0": ">=0",
    "depth_sigma_z2": ">=0",
    "correlated_fraction": "[0,1]",
    "correlated_length_px": ">=0",
    "grazing_start_deg": "[0,90]",
    "grazing_full_deg": "[0,90]",
    "thin_width_px": ">=0",
    "thin_dropout": "[0,1]",
    "edge_jump": ">0",
    "mixed_pixel_fraction": "[0,1]",
    "speckle_dropout": "[0,1]",
    "depth_unit": ">=0",
    "exposure_variation": "[0,1)",
    "white_balance_variation": "[0,1)",
    "illumination_gradient": "[0,1)",
    "read_noise": ">=0",
    "shot_noise": ">=0",
}


def ValidateRobotConfig(cfg: RobotConfig, path: str = "robot") -> None:
    """Raises ``ConfigError`` (key path, what is wrong) on a bad value."""
    CheckRules(cfg, path, _ROBOT_RULES)
    CheckTransform(cfg.X_WB, Join(path, "X_WB"))


def ValidateCameraNoiseConfig(cfg: CameraNoiseConfig, path: str = "camera_noise") -> None:
    """Raises ``ConfigError`` (key path, what is wrong) on a bad value."""
    CheckRules(cfg, path, _CAMERA_NOISE_RULES)
    Need(cfg.grazing_start_deg <= cfg.grazing_full_deg, Join(path, "grazing_start_deg"),
         f"must be <= grazing_full_deg ({cfg.grazing_full_deg}), got {cfg.grazing_start_deg}")


def ValidateCameras(cameras: typing.Mapping[str, CameraConfig], path: str = "cameras") -> None:
    """The simulated cameras: ``camera0`` (the pipeline's) present, each
    named as its key, with colour and depth, sane intrinsics and a finite
    pose. Raises ``ConfigError``."""
    Need("camera0" in cameras, path, "must contain 'camera0' (the pipeline's camera)")
    for name, cam in cameras.items():
        p = f"{path}.{name}"
        Need(cam.name == name, f"{p}.name", f"must equal its key '{name}', got '{cam.name}'")
        Need(cam.depth and cam.rgb, p, "needs rgb and depth enabled")
        Need(cam.width >= 1 and cam.height >= 1, p,
             f"width and height must be >= 1, got {cam.width} x {cam.height}")
        Need(cam.width <= MAX_IMAGE_SIDE and cam.height <= MAX_IMAGE_SIDE, p,
             f"width and height must be at most {MAX_IMAGE_SIDE} px (lmap_drake.limits), "
             f"got {cam.width} x {cam.height}")
        Need(np.isfinite(cam.fps) and cam.fps > 0, f"{p}.fps", f"must be > 0, got {cam.fps}")
        Need(0 < cam.clipping_near < cam.clipping_far, p,
             f"needs 0 < clipping_near < clipping_far, got {cam.clipping_near}, "
             f"{cam.clipping_far}")
        Need(0 < cam.z_near < cam.z_far, p,
             f"needs 0 < z_near < z_far, got {cam.z_near}, {cam.z_far}")
        fx, fy = cam.focal_x(), cam.focal_y()
        Need(np.isfinite(fx) and np.isfinite(fy) and fx > 0 and fy > 0, f"{p}.focal",
             f"must be > 0, got {fx}, {fy}")
        CheckTransform(cam.X_PB, f"{p}.X_PB")
        Need(cam.X_PB.base_frame in (None, "", "world"), f"{p}.X_PB.base_frame",
             f"must be 'world' (the pipeline's cameras are posed in the world), got "
             f"'{cam.X_PB.base_frame}'")
        for key in ("X_BC", "X_BD"):
            Need(FiniteTransform(getattr(cam, key)), f"{p}.{key}", "must be a finite pose")
        Need(not isinstance(cam.renderer_class, str) or cam.renderer_class in RENDERER_CLASSES,
             f"{p}.renderer_class", f"'{cam.renderer_class}' unknown; choose one of "
             f"{', '.join(repr(r) for r in RENDERER_CLASSES)}")
        for key in ("capture_offset", "output_delay"):
            v = getattr(cam, key)
            Need(np.isfinite(v) and v >= 0, f"{p}.{key}", f"must be >= 0, got {v}")


# Drake's settings (simulator, plant, scene graph, lights): checked at load,
# before Drake builds anything (it would fail late or accept them).
RENDERER_CLASSES = ("", "RenderEngineVtk", "RenderEngineGl", "RenderEngineGltfClient")
_PLANT_RULES = {"time_step": ">0", "penetration_allowance": ">0",
                "stiction_tolerance": ">0", "sap_near_rigid_threshold": ">=0"}
_PLANT_ENUMS = {
    "contact_model": ("point", "hydroelastic", "hydroelastic_with_fallback"),
    "discrete_contact_approximation": ("", "tamsi", "sap", "similar", "lagged"),
    "contact_surface_representation": ("triangle", "polygon"),
}
_SIMULATOR_RULES = {"max_step_size": ">0", "accuracy": ">0", "start_time": ">=0",
                    "target_realtime_rate": ">=0"}
_LIGHT_TYPES = ("point", "spot", "directional")
_LIGHT_FRAMES = ("world", "camera")
_PROXIMITY_RULES = {"hydroelastic_modulus": ">0", "resolution_hint": ">0",
                    "dynamic_friction": ">=0", "static_friction": ">=0",
                    "hunt_crossley_dissipation": ">=0", "relaxation_time": ">=0",
                    "point_stiffness": ">0", "slab_thickness": ">0", "margin": ">=0"}


def _CheckStruct(cfg, path: str, rules: dict, enums: dict = {}) -> None:
    """``rules`` / ``enums`` on a Drake-bound struct (optional fields may be None)."""
    for key, rule in rules.items():
        v = getattr(cfg, key)
        if v is not None:
            err = RuleError(v, rule)
            Need(not err, Join(path, key), err)
    for key, choices in enums.items():
        v = getattr(cfg, key)
        Need(v in choices, Join(path, key), f"'{v}' unknown; choose one of "
             f"{', '.join(repr(c) for c in choices)}")


def ValidateDrakeConfigs(simulator_config, plant_config, scene_graph_config, lights) -> None:
    """``simulator_config``, ``plant_config`` (a discrete plant: the leaves
    are deformable), ``scene_graph_config`` and ``lights`` hold values Drake
    accepts; raises ``ConfigError`` naming the key."""
    from pydrake.systems.analysis import GetIntegrationSchemes
    _CheckStruct(simulator_config, "simulator_config", _SIMULATOR_RULES,
                 {"integration_scheme": tuple(GetIntegrationSchemes())})
    _CheckStruct(plant_config, "plant_config", _PLANT_RULES, _PLANT_ENUMS)
    props = scene_graph_config.default_proximity_properties
    _CheckStruct(props, "scene_graph_config.default_proximity_properties", _PROXIMITY_RULES,
                 {"compliance_type": ("undefined", "rigid", "compliant")})
    for i, light in enumerate(lights):
        p = f"lights[{i}]"
        _CheckStruct(light, p, {"intensity": ">=0", "cone_angle": "[0,90]"},
                     {"type": _LIGHT_TYPES, "frame": _LIGHT_FRAMES})
        for key in ("attenuation_values", "position", "direction"):
            v = np.asarray(getattr(light, key), float)
            Need(np.all(np.isfinite(v)), Join(p, key), f"must be finite, got {v.tolist()}")
        Need(np.any(np.asarray(light.attenuation_values) != 0), Join(p, "attenuation_values"),
             "must not be all zero")
        Need(light.type != "directional" or np.linalg.norm(light.direction) > 0,
             Join(p, "direction"), "must not be zero for a directional light")
