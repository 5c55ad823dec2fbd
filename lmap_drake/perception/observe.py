"""One call from camera images to a ``SemanticScene`` (functional core of
the ``Perception`` system)."""
from __future__ import annotations

import numpy as np

from lmap_drake.perception.points import BuildSemanticScene, Intrinsics
from lmap_drake.perception.segmentation import MakeSegmenter
from lmap_drake.types import SemanticScene


def SemanticSceneFromImages(rgb, depth, label, camera_config, perception_config
                            ) -> SemanticScene:
    """Segments (backend ``perception_config.segmenter``) and de-projects
    camera0's images into world-frame point sets (m). ``label`` may be None
    unless the backend is ``label``."""
    K = Intrinsics.FromCameraConfig(camera_config)
    segmenter = MakeSegmenter(perception_config, K)
    seg = segmenter.Segment(rgb, depth, label)
    X_WC = camera_config.X_PB.GetDeterministicValue().GetAsMatrix4()
    d = np.asarray(getattr(depth, "data", depth))
    return BuildSemanticScene(seg.class_map, d, K, X_WC, perception_config,
                              flags=list(getattr(seg, "flags", [])),
                              instance_map=seg.instance_map, confidence=seg.confidence,
                              leaf_boundary=seg.leaf_boundary)
