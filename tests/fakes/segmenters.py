"""FAKE segmenter for the tests (under tests/: not part of the product).

``GripperAsLeafSegmenter``: the simulator's labels (the real ``label``
segmenter) with the robot's pixels called leaf, as one instance: the
failure a learned segmenter shows at the gripper's rim, made total so that
a test sees what the robot mask removes."""
from __future__ import annotations

import numpy as np

from lmap_drake.labels import LEAF, ROBOT, DecodeLabels
from lmap_drake.perception.segmentation import LabelSegmenter, Segmentation


class GripperAsLeafSegmenter(LabelSegmenter):
    """FAKE: ``label`` segmentation, robot pixels -> leaf instance 99."""
    name = "fake_gripper_as_leaf"

    def Segment(self, rgb, depth, label=None) -> Segmentation:
        seg = super().Segment(rgb, depth, label)
        robot = DecodeLabels(np.asarray(getattr(label, "data", label)))[0] == ROBOT
        seg.class_map[robot] = LEAF
        seg.instance_map[robot] = 99
        seg.confidence[(LEAF, 99)] = 1.0
        return seg
