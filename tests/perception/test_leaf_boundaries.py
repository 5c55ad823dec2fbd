"""Leaf clusters cut along the segmenter's leaf boundaries
(lmap_drake/perception/leaf_boundaries.py) and through the point pipeline."""
import numpy as np

from lmap_drake.labels import BRANCH, LEAF, LeafBoundaryMask
from lmap_drake.perception.config import PerceptionConfig
from lmap_drake.perception.leaf_boundaries import ImagePatches, SplitClustersByPatches
from lmap_drake.perception.points import BuildSemanticScene, DbscanLabels, Intrinsics

K = Intrinsics(160, 120, 300.0, 300.0, 79.5, 59.5)


def _flush_blades():
    """Two blades side by side at one depth (0.5 m, flush: one DBSCAN
    cluster), a stem in front of the left one cutting it in two; truth ids."""
    ids = np.full((120, 160), -1)
    ids[30:90, 20:80] = 0
    ids[30:90, 80:140] = 1
    cls = np.where(ids >= 0, LEAF, 0)
    cls[:, 45:48] = BRANCH                      # the stem in front of blade 0 (5 mm)
    ids[:, 45:48] = -1
    depth = np.full(cls.shape, np.inf)
    depth[cls == LEAF] = 0.5
    depth[cls == BRANCH] = 0.497               # just in front: no flying pixels at its sides
    return cls, ids, depth


def test_patches_facing_across_the_band_cannot_link_and_pieces_across_a_stem_can():
    cls, ids, _ = _flush_blades()
    leaf = cls == LEAF
    patch, cannot = ImagePatches(leaf, LeafBoundaryMask(ids))
    left_a, left_b, right = patch[60, 30], patch[60, 60], patch[60, 120]
    assert len({left_a, left_b, right}) == 3 and 0 not in (left_a, left_b, right)
    assert cannot == {tuple(sorted((left_b, right)))}    # the stem gap is no boundary
    assert (patch[leaf] > 0).all() and (patch[~leaf] == 0).all()


def test_a_cluster_of_two_flush_blades_is_cut_along_the_boundary_only():
    cls, ids, depth = _flush_blades()
    leaf = cls == LEAF
    v, u = np.nonzero(leaf)
    p = np.stack([(u - K.cx) * 0.5 / K.fx, (v - K.cy) * 0.5 / K.fy, np.full(len(u), 0.5)], 1)
    inst = DbscanLabels(p, 0.008, 15)
    assert len(np.unique(inst)) == 1                      # flush: one cluster
    patch, cannot = ImagePatches(leaf, LeafBoundaryMask(ids))
    cut = SplitClustersByPatches(p, inst, patch[v, u], cannot)
    truth = ids[v, u]
    assert len(np.unique(cut)) == 2
    for t in (0, 1):                                      # each blade one instance, stem or not
        assert len(np.unique(cut[truth == t])) == 1
    assert cut[truth == 0][0] != cut[truth == 1][0]
    none = SplitClustersByPatches(p, inst, patch[v, u], set())
    assert len(np.unique(none)) == 1


def test_the_point_pipeline_cuts_leaves_only_with_a_boundary_and_the_key_on():
    cls, ids, depth = _flush_blades()
    cls[30:90, 45:48], ids[30:90, 45:48], depth[cls == LEAF] = LEAF, 0, 0.5   # no stem
    X = np.eye(4)
    band = LeafBoundaryMask(ids)
    p = PerceptionConfig()
    assert len(np.unique(BuildSemanticScene(cls, depth, K, X, p).leaf_instance)) == 1
    two = BuildSemanticScene(cls, depth, K, X, p, leaf_boundary=band)
    assert len(np.unique(two.leaf_instance[two.leaf_instance >= 0])) == 2
    p.leaf_boundaries = False
    off = BuildSemanticScene(cls, depth, K, X, p, leaf_boundary=band)
    assert len(np.unique(off.leaf_instance)) == 1
