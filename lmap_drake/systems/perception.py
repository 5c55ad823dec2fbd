"""``Perception``: the segmentation + semantic point-cloud stage as a Drake
LeafSystem (thin shell around ``lmap_drake.perception``).

Input ports:

- ``camera0.rgb_image`` (abstract ``ImageRgba8U``): colour image.
- ``camera0.depth_image`` (abstract ``ImageDepth32F``): depth along the
  optical axis, metres; NaN / inf / 0 = no return.
- ``camera0.label_image`` (abstract ``ImageLabel16I``, optional): render
  labels (simulation only); required only by the ``label`` segmenter.
- ``camera0.X_WC`` (abstract ``RigidTransform``, optional): pose of the
  camera frame C (Drake convention: +z forward, +x right, +y down) in the
  world W. Unconnected, the fixed eye-to-hand pose ``camera_config.X_PB``
  (base frame world) is used.
- ``ur5.position`` (vector, 6, rad, optional): the arm's joints when the
  images were taken. Connected (and a ``robot`` model given), plant points
  within ``perception.robot_filter_distance`` of the robot's collision
  surfaces (gripper open and closed) are dropped: the robot self-filter.
- ``gripper.opening`` (vector, 1, m, optional): the gripper's opening when
  the images were taken (NaN or unconnected: unknown).
- With ``ur5.position`` connected, a ``robot`` model given and
  ``perception.robot_mask``, the pixels the robot covers at those joints
  (``perception.robot_mask.RobotDepthRenderer``: its visual geometry
  rendered at the camera's intrinsics and pose) are set to background
  before instances are built (``RobotPixelMask``; an unknown opening:
  pixels the robot covers at every opening, and those whose measured
  depth agrees with the robot at one of five openings).
- ``capture`` (vector, 1, optional): a view counter. Whenever its value
  exceeds the number of views already fused, the current view is fused into
  the state at the start of the next simulation step (per-step
  unrestricted-update event).

Output ports:

- ``semantic_scene`` (abstract ``SemanticScene``): the current view's
  branch / leaf / fruit points in W (metres) with instance ids and flags.
  Computed on demand in the output calc and cached by Drake until an input
  changes (the camera ports change every render, i.e. when the scene does).
- ``fused_semantic_scene`` (abstract ``SemanticScene``): the views fused so
  far (paper Sec. III-E: leaf from the newest view, fruit and branch
  accumulated); empty with flag ``no_views_fused`` until the first capture.
  Held in abstract state; ``CaptureView(context)`` fuses the current view
  directly (scripts, or an orchestrator that owns the context).
- ``num_views_fused`` (vector, 1): how many views the fused scene holds.

Intrinsics come from the scenario's ``CameraConfig`` given to the
constructor; parameters from ``PerceptionConfig``. The segmenter (a heavy
object for ``grounded_sam``) is an attribute of the system, not context
state.
"""
from __future__ import annotations

import hashlib

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.systems.framework import Context, EventStatus, LeafSystem, State
from pydrake.systems.sensors import ImageDepth32F, ImageLabel16I, ImageRgba8U

from lmap_drake.perception.fusion import FuseViews
from lmap_drake.perception.points import BuildSemanticScene, Intrinsics, RemovePointsNear
from lmap_drake.perception.robot_mask import MaskRobotPixels, RobotDepthRenderer, RobotPixelMask
from lmap_drake.perception.segmentation import MakeSegmenter, Segmenter, SegmenterError
from lmap_drake.robot import GRIPPER_MAX_WIDTH
from lmap_drake.types import SemanticScene


def _camera_pose(camera_config) -> RigidTransform:
    base = camera_config.X_PB.base_frame
    if base not in (None, "", "world"):
        raise ValueError(f"camera {camera_config.name}: X_PB.base_frame '{base}' is not the "
                         "world; connect the camera0.X_WC input port instead")
    return camera_config.X_PB.GetDeterministicValue()


class _Fused:
    """The fused scene held in the Context's abstract state. Drake copies a
    system's abstract state (``copy.deepcopy`` for Python values) before
    every per-step update, whether it acts or not; the scene is never
    changed in place (a new view makes a new scene), so the copies share it
    (a fused scene's point arrays cost ~1 ms a step to copy)."""
    __slots__ = ("scene",)

    def __init__(self, scene: SemanticScene):
        self.scene = scene

    def __deepcopy__(self, memo):
        return self


def _Fingerprint(*arrays) -> bytes:
    """A digest of the arrays' shapes and bytes (None counts as empty)."""
    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        a = np.ascontiguousarray(a if a is not None else np.zeros(0))
        h.update(repr((a.shape, a.dtype.str)).encode())
        h.update(a.data)
    return h.digest()


class Perception(LeafSystem):
    """RGB-D (+ optional labels) -> SemanticScene; see the module docstring
    for ports, frames and units."""

    def __init__(self, camera_config, config, segmenter: Segmenter | None = None,
                 robot=None):
        """``robot``: a ``planning.robot_model.RobotModel`` for the self-filter."""
        super().__init__()
        self._robot = robot
        self.set_name("perception")
        self._config = config
        self._K = Intrinsics.FromCameraConfig(camera_config)
        self._segmenter = segmenter if segmenter is not None else MakeSegmenter(config, self._K)
        self._X_WC_default = _camera_pose(camera_config)
        self._camera_config = camera_config
        self._renderer = None   # RobotDepthRenderer, made at the first masked view
        self._last = None       # (input fingerprint, scene) of the last ComputeScene
        name = camera_config.name
        self._rgb = self.DeclareAbstractInputPort(
            f"{name}.rgb_image", AbstractValue.Make(ImageRgba8U()))
        self._depth = self.DeclareAbstractInputPort(
            f"{name}.depth_image", AbstractValue.Make(ImageDepth32F()))
        self._label = self.DeclareAbstractInputPort(
            f"{name}.label_image", AbstractValue.Make(ImageLabel16I()))
        self._pose = self.DeclareAbstractInputPort(
            f"{name}.X_WC", AbstractValue.Make(RigidTransform()))
        self._q = self.DeclareVectorInputPort("ur5.position", 6)
        self._opening = self.DeclareVectorInputPort("gripper.opening", 1)
        self._capture = self.DeclareVectorInputPort("capture", 1)
        self._fused_index = self.DeclareAbstractState(
            AbstractValue.Make(_Fused(SemanticScene(flags=["no_views_fused"], num_views=0))))
        self._scene_port = self.DeclareAbstractOutputPort(
            "semantic_scene", lambda: AbstractValue.Make(SemanticScene()), self._calc_scene,
            prerequisites_of_calc={self.all_input_ports_ticket()})
        self.DeclareAbstractOutputPort(
            "fused_semantic_scene", lambda: AbstractValue.Make(SemanticScene()),
            self._calc_fused,
            prerequisites_of_calc={self.abstract_state_ticket(self._fused_index)})
        self.DeclareVectorOutputPort(
            "num_views_fused", 1,
            lambda c, out: out.SetFromVector(
                [c.get_abstract_state(self._fused_index).get_value().scene.num_views]),
            prerequisites_of_calc={self.abstract_state_ticket(self._fused_index)})
        self.DeclarePerStepUnrestrictedUpdateEvent(self._on_step)

    @property
    def segmenter(self) -> Segmenter:
        return self._segmenter

    def CameraPose(self, context: Context) -> RigidTransform:
        """X_WC from the input port, or the configured fixed pose."""
        if self._pose.HasValue(context):
            return self._pose.Eval(context)
        return self._X_WC_default

    def ComputeScene(self, context: Context) -> SemanticScene:
        """Segments the current images and builds the world-frame point sets.
        The same images, pose and joints as the last call give the last
        scene back without segmenting again: Drake recomputes this port
        after every step (the view recorder's per-step update touches its
        state even when it holds the same view), and planning asks for the
        scene of a view Perception has already fused."""
        if not (self._rgb.HasValue(context) and self._depth.HasValue(context)):
            raise SegmenterError("perception needs camera0.rgb_image and camera0.depth_image "
                                 "connected (or fixed)")
        rgb = self._rgb.Eval(context).data
        depth = self._depth.Eval(context).data
        label = None
        if self._segmenter.needs_label:
            if not self._label.HasValue(context):
                raise SegmenterError(
                    f"segmenter '{self._segmenter.name}' needs camera0.label_image "
                    "connected (simulation only); use segmenter: color_depth otherwise")
            label = self._label.Eval(context).data
        X_WC = self.CameraPose(context).GetAsMatrix4()
        distance = self._config.robot_filter_distance
        q = (self._q.Eval(context).copy() if self._robot is not None
             and self._q.HasValue(context) else None)
        mask_robot = q is not None and self._config.robot_mask
        opening = (float(self._opening.Eval(context)[0]) if mask_robot
                   and self._opening.HasValue(context) else np.nan)
        key = _Fingerprint(rgb, depth, label, X_WC, q, np.array([opening]))
        if self._last is not None and self._last[0] == key:
            return self._last[1]
        seg = self._segmenter.Segment(rgb, depth, label)
        class_map, instance_map = seg.class_map, seg.instance_map
        if mask_robot:
            class_map, instance_map = MaskRobotPixels(
                class_map, instance_map, self.RobotMask(q, opening, X_WC, depth))
        scene = BuildSemanticScene(class_map, depth, self._K, X_WC, self._config, seg.flags,
                                   instance_map, seg.confidence, seg.leaf_boundary)
        if q is not None and distance > 0:
            robot_W = np.vstack([self._robot.SurfacePoints(q, h)
                                 for h in (0.0, 0.5 * GRIPPER_MAX_WIDTH)])
            scene, _ = RemovePointsNear(scene, robot_W, distance)
        self._last = (key, scene)
        return scene

    def RobotMask(self, q: np.ndarray, opening: float, X_WC, depth: np.ndarray) -> np.ndarray:
        """(H, W) bool: the pixels the robot covers at joints ``q`` (rad) and
        gripper ``opening`` (m; NaN: unknown) seen from ``X_WC`` (4x4, W),
        against the measured ``depth`` (H, W, m); see the module docstring."""
        if self._renderer is None:
            base = self._robot.plant.GetFrameByName("base_link", self._robot.ur5)
            self._renderer = RobotDepthRenderer(base.CalcPoseInWorld(self._robot.context),
                                                self._camera_config)
        d = np.asarray(depth, float).reshape(self._renderer.height, self._renderer.width)
        cfg = self._config
        if np.isfinite(opening):
            return RobotPixelMask(self._renderer.Render(q, opening, X_WC), d,
                                  cfg.robot_mask_tolerance, cfg.robot_mask_dilate_px)
        # unknown opening: covered at every opening, or seen where the fingers
        # of one of five openings (each finger 1 cm from the next) are
        renders = [self._renderer.Render(q, w, X_WC)
                   for w in np.linspace(0.0, GRIPPER_MAX_WIDTH, 5)]
        tol, px = cfg.robot_mask_tolerance, cfg.robot_mask_dilate_px
        both = np.logical_and.reduce([RobotPixelMask(r, d, tol, px) for r in renders])
        return np.logical_or.reduce([both] + [RobotPixelMask(r, d, tol, px, in_front=False)
                                              for r in renders])

    def _calc_scene(self, context: Context, output) -> None:
        output.set_value(self.ComputeScene(context))

    def _calc_fused(self, context: Context, output) -> None:
        output.set_value(context.get_abstract_state(self._fused_index).get_value().scene)

    def _fuse(self, previous: SemanticScene, scene: SemanticScene) -> SemanticScene:
        if previous.num_views == 0:
            return scene
        return FuseViews(previous, scene, self._config.voxel_size,
                         self._config.fusion_match_distance)

    def CaptureView(self, context: Context) -> SemanticScene:
        """Fuses the current view into this system's state in ``context``
        (a mutable context of this system) and returns the fused scene."""
        state = context.get_mutable_abstract_state(self._fused_index)
        fused = self._fuse(state.get_value().scene, self._scene_port.Eval(context))
        state.set_value(_Fused(fused))
        return fused

    def _on_step(self, context: Context, state: State):
        if not self._capture.HasValue(context):
            return EventStatus.DidNothing()
        previous = context.get_abstract_state(self._fused_index).get_value().scene
        if self._capture.Eval(context)[0] <= previous.num_views:
            return EventStatus.DidNothing()
        fused = self._fuse(previous, self._scene_port.Eval(context))
        state.get_mutable_abstract_state(self._fused_index).set_value(_Fused(fused))
        return EventStatus.Succeeded()
