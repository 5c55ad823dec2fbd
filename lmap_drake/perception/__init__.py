"""Perception (paper Sec. III-A-1): segmenters, semantic point clouds,
instance clustering and view fusion. Functional core: numpy in, numpy /
``SemanticScene`` out; the LeafSystem is ``lmap_drake.systems.perception``."""
from lmap_drake.perception.fusion import FuseViews  # noqa: F401
from lmap_drake.perception.config import PerceptionConfig  # noqa: F401
from lmap_drake.perception.points import BuildSemanticScene, Intrinsics  # noqa: F401
from lmap_drake.perception.segmentation import (SEGMENTERS, ClassIou,  # noqa: F401
                                                MakeSegmenter, MissingWeightsError,
                                                Segmentation, SegmenterError)
