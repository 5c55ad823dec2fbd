"""The robot mask (``perception.robot_mask``): the robot's pixels from its
joints, rendered by Drake, on a simulated view with the gripper at the
leaf; and in the Perception system, against a segmenter that calls the
gripper leaf."""
import dataclasses as dc

import numpy as np
import pytest
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource
from scipy import ndimage

from fakes.segmenters import GripperAsLeafSegmenter
from lmap_drake.labels import LEAF, ROBOT, DecodeLabels
from lmap_drake.perception.segmentation import LabelSegmenter
from lmap_drake.perception.robot_mask import (MaskRobotPixels, RobotDepthRenderer,
                                              RobotPixelMask)
from lmap_drake.planning.robot_model import RobotModel
from lmap_drake.plants.plant_station import GetPlantModel, MakePlantStation, RenderStill
from lmap_drake.scenario import LoadScenario
from lmap_drake.systems.perception import Perception

SMALL = ("cameras: {camera0: {name: camera0, width: 320, height: 240, "
         "focal: !FocalLength {x: 228.4, y: 228.5}, center_x: 160.0, center_y: 120.0, "
         "X_PB: {base_frame: world, translation: [0.25, -0.55, 0.45], "
         "rotation: !Rpy {deg: [-105.0, 0.0, -25.0]}}}}")
# a small leaf hiding about half of the fruit (as the one-leaf suite's)
PLANT = "{plant_scene: {kind: procedural, occlusion: 0.55, leaf: {length: 0.11, width: 0.065}}}"
OPENING = 0.02  # m


@pytest.fixture(scope="module")
def at_leaf():
    """(scenario, robot model, rgb, depth, label) with the gripper 1 cm
    before the leaf's middle, approaching from above."""
    s = LoadScenario(scenario_text=[SMALL, PLANT])
    leaf = GetPlantModel(s).leaf_rest_W
    p = leaf[np.argmin(np.linalg.norm(leaf - leaf.mean(0), axis=1))]
    z = np.array([0.0, 0.0, -1.0])
    x = np.cross(z, [0.3, 0.2, 1.0])
    x /= np.linalg.norm(x)
    robot = RobotModel(s.robot.X_WB.GetDeterministicValue())
    r = robot.Ik(RigidTransform(RotationMatrix(np.c_[x, np.cross(z, x), z]), p - 0.01 * z),
                 np.asarray(s.robot.initial_q), 0.5 * OPENING, multistart=True)
    assert r.success
    s.robot.initial_q = [float(v) for v in r.q]
    s.robot.initial_gripper_width = OPENING
    rgb, depth, label = RenderStill(s)
    return s, robot, rgb, depth, label


def _render(s, q, opening):
    cam = s.cameras["camera0"]
    return RobotDepthRenderer(s.robot.X_WB.GetDeterministicValue(), cam).Render(
        q, opening, cam.X_PB.GetDeterministicValue())


def test_the_rendered_robot_covers_the_gripper_and_keeps_the_leaf(at_leaf):
    s, _, _, depth, label = at_leaf
    cls, _ = DecodeLabels(label)
    robot, leaf = cls == ROBOT, cls == LEAF
    # the view is the case: the gripper touches the leaf in the image
    assert robot.sum() > 2000 and leaf.sum() > 300
    assert (ndimage.binary_dilation(robot, iterations=2) & leaf).sum() > 50
    mask = RobotPixelMask(_render(s, s.robot.initial_q, OPENING), depth, 0.01, 0)
    assert (mask & robot).sum() >= 0.99 * robot.sum()
    assert (mask & leaf).sum() <= 0.2 * leaf.sum()
    # the leaf in front of the fingers by more than 3 mm keeps its pixels
    tight = RobotPixelMask(_render(s, s.robot.initial_q, OPENING), depth, 0.003, 0)
    assert (tight & leaf).sum() <= 0.03 * leaf.sum()
    # at other joints the mask is elsewhere: it follows q, not the image
    q = np.asarray(s.robot.initial_q) + [0.3, 0, 0, 0, 0, 0]
    assert (RobotPixelMask(_render(s, q, OPENING), depth, 0.01, 0) & robot).sum() \
        < 0.5 * robot.sum()


def test_the_mask_keeps_a_plant_in_front_and_grows_by_the_edge():
    robot = np.full((5, 7), np.inf)
    robot[1:4, 2:5] = 0.5                          # the robot at 0.5 m
    depth = np.full((5, 7), 0.8)                   # background behind it
    depth[1:4, 2:5] = 0.5
    depth[2, 3] = 0.45                             # a leaf 5 cm in front
    depth[1, 2] = np.nan                           # no return on the robot
    m = RobotPixelMask(robot, depth, 0.01, 0)
    assert m.sum() == 8 and not m[2, 3] and m[1, 2]
    grown = RobotPixelMask(robot, depth, 0.01, 1)
    assert grown.sum() == 5 * 5 - 1 and not grown[2, 3] and not grown[:, 0].any()
    assert RobotPixelMask(robot, depth, 0.01, 0, in_front=False).sum() == 8 - 1
    cls = np.full((5, 7), LEAF)
    inst = np.zeros((5, 7), int)
    c, i = MaskRobotPixels(cls, inst, m)
    assert (c[m] == 0).all() and (i[m] == -1).all() and (c[~m] == LEAF).all()
    assert (cls == LEAF).all()                     # the input is not changed
    with pytest.raises(ValueError, match="shape"):
        RobotPixelMask(robot, depth[:4], 0.01)


def _PerceptionLeaf(s, robot, opening, segmenter, **cfg):
    """Leaf points of Perception with the fake segmenter (gripper pixels
    called leaf) on the station's view at the scenario's joints."""
    builder = DiagramBuilder()
    station = builder.AddSystem(MakePlantStation(s))
    cam = s.cameras["camera0"]
    p = builder.AddSystem(Perception(cam, dc.replace(s.perception, **cfg), segmenter,
                                     robot=robot))
    for port in ("rgb_image", "depth_image", "label_image"):
        builder.Connect(station.GetOutputPort(f"camera0.{port}"),
                        p.GetInputPort(f"camera0.{port}"))
    q = builder.AddSystem(ConstantVectorSource(s.robot.initial_q))
    builder.Connect(q.get_output_port(), station.GetInputPort("ur5.position"))
    builder.Connect(q.get_output_port(), p.GetInputPort("ur5.position"))
    g = builder.AddSystem(ConstantVectorSource([s.robot.initial_gripper_width]))
    builder.Connect(g.get_output_port(), station.GetInputPort("gripper.position"))
    if opening is not None:
        o = builder.AddSystem(ConstantVectorSource([opening]))
        builder.Connect(o.get_output_port(), p.GetInputPort("gripper.opening"))
    ctx = builder.Build().CreateDefaultContext()
    return p.GetOutputPort("semantic_scene").Eval(p.GetMyContextFromRoot(ctx))


def test_perception_removes_gripper_pixels_called_leaf(at_leaf):
    """With the default self-filter (points within 1 cm of the robot's
    collision surfaces) the gripper's pixels called leaf still leave leaf
    points (the arm's far parts, the rim); the mask takes them out, with the
    gripper's opening known or not, and leaves the true leaf as it was."""
    s, robot, *_ = at_leaf
    fake = GripperAsLeafSegmenter()
    truth = _PerceptionLeaf(s, robot, OPENING, LabelSegmenter(), robot_mask=False)
    fooled = _PerceptionLeaf(s, robot, OPENING, fake, robot_mask=False)
    n_truth = len(truth.leaf_points_W)
    assert n_truth > 150
    assert len(fooled.leaf_points_W) > 1.2 * n_truth        # the filter alone lets it through
    for opening in (OPENING, None):
        masked = _PerceptionLeaf(s, robot, opening, fake, robot_mask=True)
        assert 0.97 * n_truth <= len(masked.leaf_points_W) <= 1.03 * n_truth
        assert set(np.unique(masked.leaf_instance)) == set(np.unique(truth.leaf_instance))
    # the mask alone (no point filter) keeps most of the true leaf: only
    # what lies within a centimetre in front of the gripper or at its rim
    alone = _PerceptionLeaf(s, robot, OPENING, LabelSegmenter(), robot_mask=True,
                            robot_filter_distance=0.0)
    full = _PerceptionLeaf(s, robot, OPENING, LabelSegmenter(), robot_mask=False,
                           robot_filter_distance=0.0)
    assert len(alone.leaf_points_W) >= 0.65 * len(full.leaf_points_W)
