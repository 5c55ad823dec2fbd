"""Segmenter backends on rendered scenes, and the GroundedSAM adapter."""
import numpy as np
import pytest

from lmap_drake.labels import BRANCH, FRUIT, LEAF, DecodeLabels, EncodeLabel
from lmap_drake.perception.foundation import BoxNms, ComposeMasks
from lmap_drake.perception.segmentation import (ClassIou, ColorDepthParams,
                                                ColorDepthSegmenter,
                                                DepthEdges, LabelSegmenter,
                                                MakeSegmenter, MissingWeightsError,
                                                SegmenterError, TruthClassMap)
from lmap_drake.perception.config import PerceptionConfig
from perception_scenes import BELOW_CAMERA, FruitColor, Render


@pytest.fixture(scope="module")
def views():
    return {c: Render(FruitColor(c)) for c in ("red", "yellow", "orange", "green")}


def test_label_backend_is_exact_and_robot_is_background(views):
    v = views["red"]
    seg = LabelSegmenter().Segment(v.rgb, v.depth, v.label)
    cls, inst = DecodeLabels(v.label)
    for c in (BRANCH, LEAF, FRUIT):
        assert ClassIou(seg.class_map, cls, c) == 1.0
    assert (seg.class_map == 4).sum() == 0
    assert np.all(seg.instance_map[seg.class_map == 0] == -1)
    with pytest.raises(SegmenterError, match="label_image"):
        LabelSegmenter().Segment(v.rgb, v.depth, None)


def test_label_backend_sees_the_neighbouring_plants_unless_told_not_to(views):
    """The oracle labels what the camera sees: the greenhouse's neighbouring
    plants are leaf / branch by default (an arm must keep clear of them in a
    real row), background with ``perception.label_neighbours: false``."""
    from lmap_drake.labels import NEIGHBOUR_INSTANCE, EncodeNeighbourLabel
    label = np.zeros((4, 6), np.int32)
    label[:2, :2] = EncodeNeighbourLabel(LEAF)
    label[3, 5] = EncodeNeighbourLabel(BRANCH)
    label[2, 3] = EncodeLabel(FRUIT, 0)
    depth = np.ones((4, 6))
    K = views["red"].K
    seen = MakeSegmenter(PerceptionConfig(segmenter="label"), K).Segment(None, depth, label)
    assert (seen.class_map[:2, :2] == LEAF).all() and seen.class_map[3, 5] == BRANCH
    assert (seen.instance_map[:2, :2] >= NEIGHBOUR_INSTANCE).all()
    hidden = MakeSegmenter(PerceptionConfig(segmenter="label", label_neighbours=False),
                           K).Segment(None, depth, label)
    assert (hidden.class_map[:2, :2] == 0).all() and hidden.class_map[3, 5] == 0
    for seg in (seen, hidden):
        assert seg.class_map[2, 3] == FRUIT and seg.instance_map[2, 3] == 0
    # the evaluations' truth leaves the neighbours out, whatever the oracle sees
    assert (TruthClassMap(label) == hidden.class_map).all()


@pytest.mark.parametrize("color", ["red", "yellow", "orange"])
def test_color_depth_backend_meets_iou_targets(views, color):
    v = views[color]
    seg = ColorDepthSegmenter(v.K).Segment(v.rgb, v.depth)  # no label image given
    truth = TruthClassMap(v.label)
    assert ClassIou(seg.class_map, truth, FRUIT) >= 0.9
    assert ClassIou(seg.class_map, truth, LEAF) >= 0.8
    assert ClassIou(seg.class_map, truth, BRANCH) >= 0.7
    # one fruit and one leaf instance
    assert seg.instance_map[seg.class_map == FRUIT].max() == 0
    assert seg.instance_map[seg.class_map == LEAF].max() == 0


def test_color_depth_finds_green_fruit_by_shape():
    """Green fruit on green leaves: found by geometry (its surface is curved,
    the leaf's is flat) when enough of it is visible."""
    v = Render(FruitColor("green"), camera=BELOW_CAMERA)
    seg = ColorDepthSegmenter(v.K).Segment(v.rgb, v.depth)
    truth = TruthClassMap(v.label)
    assert "green_fruit_detected" in seg.flags
    assert ClassIou(seg.class_map, truth, FRUIT) >= 0.9
    assert ClassIou(seg.class_map, truth, LEAF) >= 0.8
    # switched off, the green fruit is (wrongly) leaf: the geometry cue matters
    off = ColorDepthSegmenter(v.K, ColorDepthParams(detect_green_fruit=False))
    assert ClassIou(off.Segment(v.rgb, v.depth).class_map, truth, FRUIT) < 0.5


def test_color_depth_ignores_what_is_beyond_the_depth_cut(views):
    v = views["red"]
    cfg = PerceptionConfig(segmenter="color_depth", depth_cut=0.3)  # plant is ~0.5 m away
    seg = MakeSegmenter(cfg, v.K).Segment(v.rgb, v.depth)
    assert (seg.class_map > 0).sum() == 0


def test_color_depth_survives_nan_depth(views):
    v = views["red"]
    depth = v.depth.copy()
    depth[::2] = np.nan
    seg = ColorDepthSegmenter(v.K).Segment(v.rgb, depth)
    assert np.all(seg.class_map[::2] == 0)
    empty = ColorDepthSegmenter(v.K).Segment(v.rgb, np.full_like(depth, np.nan))
    assert (empty.class_map == 0).all() and "no_valid_depth" in empty.flags


def test_depth_edges_mark_far_side_only():
    d = np.ones((4, 6))
    d[:, 3:] = 1.5
    e = DepthEdges(d, 0.01)
    assert e[:, 3].all() and not e[:, 2].any() and e.sum() == 4


def test_bad_segmenter_name_is_a_clear_error(views):
    with pytest.raises(SegmenterError, match="unknown.*color_depth"):
        MakeSegmenter(PerceptionConfig(segmenter="magic"), views["red"].K)


def test_grounded_sam_missing_weights_names_file_and_key(tmp_path, views):
    cfg = PerceptionConfig(segmenter="grounded_sam")
    with pytest.raises(MissingWeightsError, match="perception.grounded_sam_config is not set"):
        MakeSegmenter(cfg, views["red"].K)
    cfg.grounded_sam_config = str(tmp_path / "GroundingDINO_SwinT_OGC.py")
    (tmp_path / "GroundingDINO_SwinT_OGC.py").write_text("# config")
    cfg.grounded_sam_checkpoint = str(tmp_path / "groundingdino_swint_ogc.pth")
    cfg.sam_checkpoint = str(tmp_path / "sam_vit_h.pth")
    with pytest.raises(MissingWeightsError) as err:
        MakeSegmenter(cfg, views["red"].K)
    msg = str(err.value)
    assert "groundingdino_swint_ogc.pth" in msg and "perception.grounded_sam_checkpoint" in msg
    assert isinstance(err.value, FileNotFoundError)


def test_grounded_sam_postprocessing():
    boxes = np.array([[0, 0, 10, 10], [0, 0, 10, 9.5], [20, 20, 30, 30]], float)
    assert BoxNms(boxes, np.array([0.9, 0.8, 0.5]), 0.8).tolist() == [0, 2]
    assert BoxNms(boxes, np.array([0.9, 0.8, 0.5]), 0.99).tolist() == [0, 1, 2]
    masks = np.zeros((3, 5, 5), bool)
    masks[0] = True                      # leaf, large
    masks[1, 1:3, 1:3] = True            # sweet pepper, on top
    masks[2, 4, :] = True                # unknown phrase: ignored
    seg = ComposeMasks(masks, ["leaf", "sweet pepper", "pot"], (5, 5))
    assert (seg.class_map == FRUIT).sum() == 4
    assert (seg.class_map == LEAF).sum() == 21
    assert seg.instance_map[1, 1] == 0


def test_fruit_border_snaps_to_the_leafs_depth_edge():
    """Leaf pixels a network called fruit (in front of the fruit, continuous
    with the leaf) become leaf again; the fruit's own curved surface stays."""
    from lmap_drake.perception.segmentation import SnapFruitToDepthEdges
    rng = np.random.default_rng(0)
    H, W = 40, 60
    v, u = np.mgrid[0:H, 0:W]
    # a round fruit behind (its front bulges 2 cm toward the camera) ...
    r2 = ((u - 40) ** 2 + (v - 20) ** 2) / 15.0 ** 2
    depth = np.where(r2 < 1, 0.60 - 0.02 * np.sqrt(np.clip(1 - r2, 0, 1)), np.inf)
    truth = np.where(r2 < 1, FRUIT, 0)
    # ... and a leaf 3 cm in front of it covering the left part
    leaf = u < 35
    depth = np.where(leaf, 0.55, depth) + rng.normal(0, 0.0015, (H, W))
    truth = np.where(leaf, LEAF, truth)
    pred = truth.copy()
    pred[(u >= 32) & (u < 35) & (r2 < 1.2)] = FRUIT      # 3 px of leaf called fruit
    out = SnapFruitToDepthEdges(pred, depth)
    assert ClassIou(out, truth, FRUIT) == 1.0 and ClassIou(out, truth, LEAF) == 1.0
    # a fruit with no leaf next to it is left alone, bulge included
    alone = np.where(r2 < 1, FRUIT, np.where(u < 5, LEAF, 0))
    d_alone = np.where(r2 < 1, 0.60 - 0.02 * np.sqrt(np.clip(1 - r2, 0, 1)),
                       np.where(u < 5, 0.58, np.inf))
    assert np.array_equal(SnapFruitToDepthEdges(alone, d_alone), alone)


def test_fruit_instance_truth_finds_a_stalk_taken_for_a_fruit():
    """A predicted fruit instance whose pixels are branch in the truth is a
    phantom (fruit fraction < 0.5); a real one is not; tiny ones are left
    out."""
    from lmap_drake.labels import BRANCH, FRUIT, LEAF
    from lmap_drake.perception.segmentation import FruitInstanceTruth, Segmentation
    truth = np.zeros((40, 40), np.int64)
    truth[0:10, 0:10] = FRUIT
    truth[20:30, 0:6] = BRANCH
    truth[20:30, 6:10] = LEAF
    cls = np.zeros_like(truth)
    inst = np.full(truth.shape, -1, np.int64)
    cls[0:10, 0:10], inst[0:10, 0:10] = FRUIT, 0          # a real fruit, 100 px
    cls[20:30, 0:10], inst[20:30, 0:10] = FRUIT, 1        # stalk + leaf called fruit
    cls[35:37, 35:37], inst[35:37, 35:37] = FRUIT, 2      # 4 px: left out
    rows = FruitInstanceTruth(Segmentation(cls, inst), truth, min_pixels=50)
    assert [r["pixels"] for r in rows] == [100, 100]
    assert rows[0]["fruit"] == 1.0
    assert rows[1]["fruit"] == 0.0 and rows[1]["branch"] == 0.6 and rows[1]["leaf"] == 0.4


def test_pixel_instances_of_leaves_are_cut_at_the_leaf_boundary():
    from lmap_drake.labels import LeafBoundaryMask
    from lmap_drake.perception.segmentation import InstancesFromComponents
    ids = np.full((60, 80), -1)
    ids[10:50, 10:40] = 0
    ids[10:50, 40:70] = 1                  # flush, one depth, one rectangle: no neck
    cls = np.where(ids >= 0, LEAF, 0)
    depth = np.where(ids >= 0, 0.5, np.inf)
    one = InstancesFromComponents(cls, depth)
    assert len(np.unique(one[cls == LEAF])) == 1
    two = InstancesFromComponents(cls, depth, leaf_boundary=LeafBoundaryMask(ids))
    assert len(np.unique(two[cls == LEAF])) == 2
    for t in (0, 1):                       # band pixels went to their own side
        assert len(np.unique(two[ids == t])) == 1

