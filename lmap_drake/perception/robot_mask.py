"""The robot's pixels from its joints (the robot mask): before instances are
built, pixels the UR5 + 2F-85 covers at the view's joints are taken out of
leaf / fruit / branch (set to background).

``RobotDepthRenderer`` renders the robot's own visual (perception-role)
geometry with Drake's ``RenderEngineVtk`` at the joints and camera pose of
a view: a depth image, metres along the optical axis, +inf where the robot
is not. It needs no label image and no simulator: the joints come from the
station (the simulated plant, or ``ur_rtde`` on hardware), so the same mask
runs in simulation, replay and on the real robot. ``RobotPixelMask``
compares it with the measured depth; ``MaskRobotPixels`` applies the mask
to a segmentation. The point self-filter (``points.RemovePointsNear``)
stays after it: it removes what is near the robot in 3D, this removes what
the robot covers in the image (its rim, where a segmenter's few "leaf"
pixels form an instance the point filter misses).
"""
from __future__ import annotations

import numpy as np
from pydrake.geometry import (DepthRange, DepthRenderCamera, MakeRenderEngineVtk,
                              RenderCameraCore, RenderEngineVtkParams)
from pydrake.math import RigidTransform
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.systems.framework import DiagramBuilder
from scipy import ndimage

from lmap_drake.labels import BACKGROUND
from lmap_drake.robot import AddUr5AndGripper

_RENDERER = "robot_mask"


def RobotPixelMask(robot_depth: np.ndarray, depth: np.ndarray, tolerance: float,
                   dilate_px: int = 0, in_front: bool = True) -> np.ndarray:
    """(H, W) bool: the pixels the robot covers. ``robot_depth`` (H, W, m):
    the robot's rendered depth (+inf / NaN / <= 0 where it is not);
    ``depth`` (H, W, m): the measured depth (NaN, inf or <= 0: no return).
    A robot pixel counts when the measured surface is not nearer than the
    robot by more than ``tolerance`` (m): then the camera sees the robot
    there (or, farther, a rim pixel mixed with what lies behind it, or a
    no-return); where the plant is measured in front of the robot, the
    pixel is the plant's. With ``in_front`` False only pixels whose measured
    depth lies within ``tolerance`` of the robot's count (for a rendered
    pose that may be off, e.g. an unknown gripper opening). The robot's
    silhouette is first grown by ``dilate_px`` pixels (the depth camera's
    edge noise at its rim), a grown pixel at the nearest robot depth beside
    it: a plant surface in front of the robot's edge keeps its pixels."""
    r = np.asarray(robot_depth, float)
    d = np.asarray(depth, float)
    if r.shape != d.shape:
        raise ValueError(f"robot depth {r.shape} and measured depth {d.shape} differ in shape")
    r = np.where(np.isfinite(r) & (r > 0), r, np.inf)
    if dilate_px > 0:      # each pixel takes the nearest robot depth within dilate_px
        r = ndimage.minimum_filter(r, size=2 * int(dilate_px) + 1, mode="constant",
                                   cval=np.inf)
    d = np.where(np.isfinite(d) & (d > 0), d, np.inf)
    robot = np.isfinite(r)
    with np.errstate(invalid="ignore"):
        if in_front:
            return robot & (d >= r - tolerance)
        return robot & (np.abs(d - r) <= tolerance)


def MaskRobotPixels(class_map: np.ndarray, instance_map: np.ndarray | None,
                    mask: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Copies of ``class_map`` (H, W, label ids) and ``instance_map``
    (H, W or None) with the ``mask`` pixels set to background (class
    ``BACKGROUND``, instance -1)."""
    cls = np.array(class_map, copy=True)
    cls[mask] = BACKGROUND
    if instance_map is None:
        return cls, None
    inst = np.array(instance_map, copy=True)
    inst[mask] = -1
    return cls, inst


class RobotDepthRenderer:
    """The UR5 + 2F-85 (base at ``X_WB`` in the world) alone in a SceneGraph
    with a ``RenderEngineVtk``; ``Render`` gives its depth image as a
    camera of ``camera_config`` (a ``pydrake.systems.sensors.CameraConfig``:
    intrinsics, clipping and depth range) sees it."""

    def __init__(self, X_WB: RigidTransform, camera_config):
        builder = DiagramBuilder()
        self._plant, self._scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
        AddUr5AndGripper(self._plant, X_WB)
        self._plant.Finalize()
        self._scene_graph.AddRenderer(_RENDERER, MakeRenderEngineVtk(RenderEngineVtkParams()))
        self._diagram = builder.Build()
        self._context = self._diagram.CreateDefaultContext()
        self._plant_context = self._plant.GetMyMutableContextFromRoot(self._context)
        self._sg_context = self._scene_graph.GetMyContextFromRoot(self._context)
        _, depth_camera = camera_config.MakeCameras()
        core = depth_camera.core()
        # the robot's depth down to the near clipping plane: an arm nearer
        # than the sensor's minimum range is still the robot (no return there)
        clip = core.clipping()
        self._camera = DepthRenderCamera(
            RenderCameraCore(_RENDERER, core.intrinsics(), clip,
                             core.sensor_pose_in_camera_body()),
            DepthRange(clip.near(), clip.far()))
        self.width = core.intrinsics().width()
        self.height = core.intrinsics().height()

    def Render(self, q: np.ndarray, opening: float, X_WC) -> np.ndarray:
        """(H, W) float32 depth (m along the optical axis; +inf where the
        robot is not; nearer than the sensor's minimum range included) of the robot at
        the 6 UR5 joints ``q`` (rad) and gripper ``opening`` (m, both fingers)
        seen from the camera body pose ``X_WC`` (RigidTransform or 4x4, W)."""
        half = 0.5 * float(opening)
        self._plant.SetPositions(self._plant_context,
                                 np.r_[np.asarray(q, float).ravel()[:6], half, half])
        X = X_WC if isinstance(X_WC, RigidTransform) else RigidTransform(np.asarray(X_WC, float))
        query = self._scene_graph.get_query_output_port().Eval(self._sg_context)
        image = query.RenderDepthImage(self._camera, self._scene_graph.world_frame_id(), X)
        d = np.array(image.data[..., 0], np.float32)
        d[~(d > 0)] = np.inf          # too close (0) or nothing (inf) is no robot
        return d
