"""The SAM backend (``segmenter: sam``) end to end on a rendered view, with a
tiny randomly initialised SAM that the test writes to a local checkpoint
(the real segment_anything model classes; nothing downloaded), and its
errors before anything is built."""
import importlib.util

import numpy as np
import pytest
import torch

from lmap_drake.scenario import LoadScenario, ScenarioError
from lmap_drake.labels import BRANCH, FRUIT, LEAF
from lmap_drake.perception.config import PerceptionConfig
from lmap_drake.perception.foundation import (BuildSam, ComposePromptedMasks,
                                              FoundationPackageError, LoadSam, Prompt,
                                              PromptsFromSegmentation, SamArchitecture,
                                              SamMasks, SamSegmenter)
from lmap_drake.perception.segmentation import (LabelSegmenter, MakeSegmenter,
                                                MissingWeightsError)
from perception_scenes import Render

# A SAM a few hundred kB large: 2 ViT blocks (one windowed, one global) of
# width 32 on a 256 px image, a 32-wide mask decoder.
TINY = dict(embed_dim=32, patch_size=16, img_size=256, depth=2, num_heads=2,
            global_attn_indexes=[1], window_size=7, mlp_ratio=2.0, out_chans=32,
            mask_in_chans=8, decoder_dim=32, decoder_depth=2, decoder_mlp_dim=64,
            decoder_heads=8, num_multimask_outputs=3, iou_head_depth=3, iou_head_hidden_dim=32)


@pytest.fixture(scope="module")
def tiny_sam(tmp_path_factory):
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("sam") / "sam_tiny.pth"
    torch.save(BuildSam(TINY).state_dict(), path)
    return path


@pytest.fixture(scope="module")
def view():
    return Render()


def test_the_architecture_is_read_from_the_checkpoint(tiny_sam):
    sd = torch.load(tiny_sam, weights_only=True)
    assert SamArchitecture(sd) == TINY
    sam = LoadSam(tiny_sam, "auto")
    assert sam.image_encoder.img_size == 256 and len(sam.image_encoder.blocks) == 2
    with pytest.raises(MissingWeightsError, match="not vit_b.*perception.sam_model_type"):
        LoadSam(tiny_sam, "vit_b")


def test_sam_backend_end_to_end_on_a_rendered_view(tiny_sam, view):
    cfg = PerceptionConfig(segmenter="sam", sam_checkpoint=str(tiny_sam), sam_model_type="auto",
                           sam_prompts="label")
    seg = MakeSegmenter(cfg, view.K)
    assert isinstance(seg, SamSegmenter)
    out = seg.Segment(view.rgb, view.depth, view.label)
    H, W = view.depth.shape
    assert out.class_map.shape == out.instance_map.shape == (H, W)
    assert set(np.unique(out.class_map)) <= {0, BRANCH, LEAF, FRUIT}
    assert np.all((out.instance_map >= 0) == (out.class_map != 0))
    # prompted by the labels' instances: one SAM mask per prompt
    prompts = PromptsFromSegmentation(LabelSegmenter().Segment(None, None, view.label), 30)
    assert {p.class_id for p in prompts} == {BRANCH, LEAF, FRUIT}
    instances = out.Instances()
    assert 1 <= len(instances) <= len(prompts)
    for c, i, n, conf in instances:
        assert n > 0 and 0.0 <= conf <= 1.0 and out.confidence[(c, i)] == conf
        assert c in {p.class_id for p in prompts}
    # nothing beyond the depth cut
    far = ~(np.isfinite(view.depth) & (view.depth > 0) & (view.depth <= cfg.depth_cut))
    assert not (out.class_map[far] != 0).any()
    rgb = np.ascontiguousarray(view.rgb[..., :3])
    masks, scores = SamMasks(seg.sam, rgb, np.stack([p.box for p in prompts]),
                             np.stack([p.point for p in prompts]))
    assert masks.shape == (len(prompts), H, W) and masks.dtype == bool
    assert scores.shape == (len(prompts),) and np.all(np.isfinite(scores))


def test_sam_prompted_by_segnet_is_the_default(tiny_sam, view):
    cfg = PerceptionConfig(segmenter="sam", sam_checkpoint=str(tiny_sam), sam_model_type="auto")
    seg = MakeSegmenter(cfg, view.K)
    assert seg.prompter.name == "segnet"
    out = seg.Segment(view.rgb, view.depth)          # no label image
    assert out.class_map.shape == view.depth.shape
    assert all(0.0 <= conf <= 1.0 for *_, conf in out.Instances())


def test_prompts_map_to_their_masks():
    cls = np.zeros((20, 30), np.int64)
    inst = np.full(cls.shape, -1, np.int64)
    cls[2:18, 2:20], inst[2:18, 2:20] = LEAF, 0
    cls[5:9, 22:28], inst[5:9, 22:28] = FRUIT, 0
    from lmap_drake.perception.segmentation import Segmentation
    prompts = PromptsFromSegmentation(Segmentation(cls, inst, [], {(LEAF, 0): 0.8}), 10)
    assert [(p.class_id, p.confidence) for p in prompts] == [(LEAF, 0.8), (FRUIT, 1.0)]
    assert prompts[0].box.tolist() == [2, 2, 20, 18]
    assert 2 <= prompts[0].point[0] <= 20 and 2 <= prompts[0].point[1] <= 18
    masks = np.zeros((2,) + cls.shape, bool)
    masks[0, 0:20, 0:25] = True                       # the leaf prompt's mask, large
    masks[1, 4:10, 21:29] = True                      # the fruit's, on top
    seg = ComposePromptedMasks(masks, prompts, np.array([0.5, 1.3]))
    assert (seg.class_map == FRUIT).sum() == 6 * 8
    assert (seg.class_map == LEAF).sum() == 20 * 25 - 4 * 6  # under the fruit's mask: fruit
    assert seg.confidence == {(LEAF, 0): 0.4, (FRUIT, 0): 1.0}


def test_missing_checkpoint_or_package_names_the_key(tmp_path, view, monkeypatch):
    with pytest.raises(ScenarioError, match="perception.sam_checkpoint must name"):
        LoadScenario(scenario_text="{perception: {segmenter: sam}}")
    missing = tmp_path / "sam_vit_b_01ec64.pth"
    with pytest.raises(ScenarioError, match=f"perception.sam_checkpoint no file at {missing}"):
        LoadScenario(scenario_text=f"{{perception: {{segmenter: sam, sam_checkpoint: {missing}}}}}")
    cfg = PerceptionConfig(segmenter="sam", sam_checkpoint=str(missing))
    with pytest.raises(MissingWeightsError, match="perception.sam_checkpoint"):
        MakeSegmenter(cfg, view.K)
    missing.write_bytes(b"not a checkpoint")
    with pytest.raises(MissingWeightsError, match="could not read the SAM checkpoint"):
        MakeSegmenter(cfg, view.K)
    torch.save({"w": torch.zeros(2)}, missing)
    with pytest.raises(MissingWeightsError, match="is not a SAM"):
        MakeSegmenter(cfg, view.K)
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "segment_anything" else
                        find_spec(name, *a))
    with pytest.raises(FoundationPackageError, match=r"'segment_anything' is not installed.*"
                                                     r"\.\[foundation\]"):
        MakeSegmenter(cfg, view.K)
    with pytest.raises(ScenarioError, match=r"perception.segmenter sam needs the package"):
        LoadScenario(scenario_text=f"{{perception: {{segmenter: sam, sam_checkpoint: {missing}}}}}")


def test_every_backend_gives_each_instance_a_confidence(view):
    for name in ("segnet", "label"):
        seg = MakeSegmenter(PerceptionConfig(segmenter=name), view.K).Segment(
            view.rgb, view.depth, view.label)
        inst = seg.Instances()
        assert inst and all(0.0 <= conf <= 1.0 for *_, conf in inst), name
    # color_depth has no score model: its instances carry none (NaN), and
    # the planner takes them as what they are called (targets.LowConfidence)
    inst = MakeSegmenter(PerceptionConfig(segmenter="color_depth"), view.K).Segment(
        view.rgb, view.depth).Instances()
    assert inst and all(np.isnan(conf) for *_, conf in inst)
    seg = MakeSegmenter(PerceptionConfig(segmenter="segnet"), view.K).Segment(view.rgb, view.depth)
    fruit = [conf for c, i, n, conf in seg.Instances() if c == FRUIT and n >= 100]
    assert fruit and max(fruit) > 0.8      # the clearly seen fruit, segnet is sure of it
