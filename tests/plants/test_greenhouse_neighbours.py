"""The greenhouse's neighbouring row carries the neighbour labels (leaf and
branch to training, background to the label oracle and scoring), and the
segmentation evaluation leaves its pixels out of the class IoUs."""
import types

import numpy as np

from lmap_drake.labels import (BACKGROUND, BRANCH, FRUIT, LEAF, DecodeLabels,
                               EncodeNeighbourLabel, NeighbourClassMap)
from lmap_drake.plants.plant_station import RenderStill
from lmap_drake.scenario import LoadScenario
from lmap_drake.studies.segmentation import ViewRow

SCENE = """plant_scene:
  kind: greenhouse
  greenhouse: {seed: 3, num_stems: 1, num_leaves: 15, max_fem_leaves: 1,
               num_random_fruits: 0, textures: false, neighbour_row: %s}
camera_noise: {enabled: false}
"""


def test_neighbour_row_is_labelled_leaf_and_branch_apart_from_the_plant():
    _, _, label = RenderStill(LoadScenario(scenario_text=SCENE % "true"))
    nb = NeighbourClassMap(label)
    assert (nb == LEAF).sum() > 2000 and (nb == BRANCH).sum() > 50
    cls, _ = DecodeLabels(label)
    assert (cls[nb > 0] == BACKGROUND).all()      # the oracle and scoring: background
    _, _, label0 = RenderStill(LoadScenario(scenario_text=SCENE % "false"))
    assert not NeighbourClassMap(label0).any()
    own = DecodeLabels(label0)[0]
    # the plant's own pixels keep their labels wherever no neighbour hides them
    free = nb == 0
    assert (cls[free & (own > 0)] == own[free & (own > 0)]).mean() > 0.99


def test_view_row_leaves_neighbour_pixels_out_of_the_ious():
    truth = np.zeros((10, 10), np.int64)
    truth[:, :5] = LEAF
    label = np.zeros((10, 10), np.int64)
    label[:, :5] = 200
    label[:, 5:] = EncodeNeighbourLabel(LEAF)     # a neighbour's leaf, truth background
    pred = np.full((10, 10), LEAF)                # the segmenter calls it leaf: not wrong
    pred[0, 9] = FRUIT
    inst = np.where(pred == FRUIT, 0, -1)
    seg = types.SimpleNamespace(class_map=pred, instance_map=inst, flags=[])
    row = ViewRow(seg, truth, label, np.zeros((10, 10, 3), np.uint8))
    assert row["leaf_iou"] == 1.0 and row["neighbour_pixels"] == 50
    assert row["fruit_iou"] is None


def test_view_row_reports_the_ious_without_the_robot_pixels():
    label = np.full((10, 10), 200, np.int16)      # leaf 0
    label[:, 8:] = 400                            # the robot
    truth = np.where(label == 200, LEAF, BACKGROUND)
    pred = np.full((10, 10), LEAF)                # leaf called on the robot's pixels too
    seg = types.SimpleNamespace(class_map=pred, instance_map=np.zeros((10, 10), int), flags=[])
    row = ViewRow(seg, truth, label, np.zeros((10, 10, 3), np.uint8))
    assert row["leaf_iou"] == 0.8
    assert row["without_robot"]["leaf_iou"] == 1.0
