"""Foundation-model segmenters from local files (the optional extra
``pip install -e '.[foundation]'``); nothing is ever downloaded.

- ``sam``: Segment Anything (SAM, ``segment_anything``) prompted by the
  project's own detections. A prompting backend (``perception.sam_prompts``:
  ``segnet`` by default, ``color_depth`` or ``label``) finds the branch,
  leaf and fruit instances; each instance of at least
  ``sam_min_prompt_pixels`` pixels becomes one SAM prompt (its bounding box
  and its innermost pixel as a foreground point), and SAM's mask for it
  becomes an instance of the prompt's class. The instance's confidence is
  SAM's predicted IoU of its mask (clipped to [0, 1]) times the prompt's.
- ``grounded_sam``: GroundingDINO (text-prompted boxes) + SAM (box-prompted
  masks), prompts ``branch. leaf. sweet pepper.``, box/text thresholds
  0.25, NMS 0.8 as in the authors' code.

The SAM architecture (ViT width, depth, heads, windowed and global
attention blocks, image size, decoder width) is read from the checkpoint's
tensors, so the official ViT-H/L/B checkpoints and any smaller
configuration (the tests build a tiny randomly initialised one) load the
same way. ``segment_anything``'s package ``__init__`` imports its predictor,
which needs torchvision; torchvision from the registry does not import
beside this project's CPU torch build, so when it is missing only the
package's model classes (``segment_anything.modeling``, torch only) are
imported and the few lines of pre- and post-processing are done here.

Images: ``rgb`` HxWx3(4) uint8, ``depth`` HxW float metres along the
optical axis (NaN/inf/0 = no return).
"""
from __future__ import annotations

import dataclasses as dc
import importlib
import importlib.util
import pickle
import sys
from functools import partial
from pathlib import Path

import numpy as np
import torch
from PIL import Image
from scipy import ndimage

from lmap_drake.errors import InputError
from lmap_drake.labels import BACKGROUND, BRANCH, FRUIT, LEAF
from lmap_drake.paths import REPO_ROOT
from lmap_drake.perception.points import Intrinsics, ValidDepthMask
from lmap_drake.perception.segmentation import (MissingWeightsError, Segmentation, Segmenter,
                                                SegmenterError, _depth2, _rgb3)

INSTALL_HINT = "pip install -e '.[foundation]'"
# Official SAM encoders: (embed_dim, depth) per perception.sam_model_type.
SAM_TYPES = {"vit_h": (1280, 32), "vit_l": (1024, 24), "vit_b": (768, 12)}


class FoundationPackageError(InputError, ImportError):
    """A foundation-model package is not installed."""


def SamCheckpointPath(cfg) -> Path:
    """``perception.sam_checkpoint`` as a path (relative paths from the
    repository root, as ``segnet_weights``); ``MissingWeightsError`` naming
    the key when it is unset or no file is there."""
    if not cfg.sam_checkpoint:
        raise MissingWeightsError(
            f"{cfg.segmenter} segmenter: perception.sam_checkpoint is not set; it must name "
            f"the local SAM checkpoint (.pth). Nothing is downloaded: see "
            f"docs/how-to/foundation-segmenter.md, or use segmenter: segnet.")
    path = Path(cfg.sam_checkpoint)
    path = path if path.is_absolute() else REPO_ROOT / path
    if not path.is_file():
        raise MissingWeightsError(
            f"{cfg.segmenter} segmenter: SAM checkpoint not found at '{path}' "
            f"(perception.sam_checkpoint). Nothing is downloaded: put the file there "
            f"(docs/how-to/foundation-segmenter.md), or use segmenter: segnet.")
    return path


def CheckSamPackage(segmenter: str = "sam") -> None:
    """``FoundationPackageError`` when ``segment_anything`` is not installed."""
    if importlib.util.find_spec("segment_anything") is None:
        raise FoundationPackageError(
            f"{segmenter} segmenter (perception.segmenter): the package 'segment_anything' "
            f"is not installed; install the extra with {INSTALL_HINT}, or use segmenter: "
            f"segnet")


def SamModeling():
    """The ``segment_anything.modeling`` module (SAM's model classes)."""
    CheckSamPackage()
    if "segment_anything" not in sys.modules:
        try:
            importlib.import_module("segment_anything")
        except Exception:  # its predictor's torchvision is missing or broken
            for name in [n for n in sys.modules if n.startswith("segment_anything")]:
                del sys.modules[name]
            spec = importlib.util.find_spec("segment_anything")
            # the package without running its __init__: the model classes need only torch
            sys.modules["segment_anything"] = importlib.util.module_from_spec(spec)
    return importlib.import_module("segment_anything.modeling")


def SamArchitecture(sd: dict) -> dict:
    """SAM's configuration read from a checkpoint's tensors (see the module
    docstring); ``KeyError`` / ``ValueError`` when it is not a SAM state dict."""
    proj = sd["image_encoder.patch_embed.proj.weight"]
    embed_dim, patch = int(proj.shape[0]), int(proj.shape[2])
    grid = int(sd["image_encoder.pos_embed"].shape[1])
    depth = 0
    while f"image_encoder.blocks.{depth}.norm1.weight" in sd:
        depth += 1
    if depth == 0:
        raise ValueError("no image encoder blocks")
    head_dim = int(sd["image_encoder.blocks.0.attn.rel_pos_h"].shape[1])
    sizes = [(int(sd[f"image_encoder.blocks.{i}.attn.rel_pos_h"].shape[0]) + 1) // 2
             for i in range(depth)]
    global_idx = [i for i, s in enumerate(sizes) if s == grid]
    windows = {s for s in sizes if s != grid}
    if len(windows) > 1:
        raise ValueError(f"several attention window sizes {sorted(windows)}")
    dim = int(sd["mask_decoder.iou_token.weight"].shape[1])
    dec_depth = 0
    while f"mask_decoder.transformer.layers.{dec_depth}.norm1.weight" in sd:
        dec_depth += 1
    return {"embed_dim": embed_dim, "patch_size": patch, "img_size": grid * patch,
            "depth": depth, "num_heads": embed_dim // head_dim,
            "global_attn_indexes": global_idx, "window_size": windows.pop() if windows else 0,
            "mlp_ratio": sd["image_encoder.blocks.0.mlp.lin1.weight"].shape[0] / embed_dim,
            "out_chans": int(sd["image_encoder.neck.0.weight"].shape[0]),
            "mask_in_chans": int(sd["prompt_encoder.mask_downscaling.3.weight"].shape[0]),
            "decoder_dim": dim, "decoder_depth": dec_depth,
            "decoder_mlp_dim": int(sd["mask_decoder.transformer.layers.0.mlp.lin1.weight"]
                                   .shape[0]),
            "decoder_heads": 8 if dim % 16 == 0 else 1,
            "num_multimask_outputs": int(sd["mask_decoder.mask_tokens.weight"].shape[0]) - 1,
            "iou_head_depth": sum(k.startswith("mask_decoder.iou_prediction_head.layers.")
                                  and k.endswith(".weight") for k in sd),
            "iou_head_hidden_dim": int(
                sd["mask_decoder.iou_prediction_head.layers.0.weight"].shape[0])}


def BuildSam(arch: dict):
    """An untrained SAM (eval mode) of the configuration ``arch``
    (``SamArchitecture``'s keys)."""
    m = SamModeling()
    a = arch
    grid = a["img_size"] // a["patch_size"]
    sam = m.Sam(
        image_encoder=m.ImageEncoderViT(
            depth=a["depth"], embed_dim=a["embed_dim"], img_size=a["img_size"],
            mlp_ratio=a["mlp_ratio"], norm_layer=partial(torch.nn.LayerNorm, eps=1e-6),
            num_heads=a["num_heads"], patch_size=a["patch_size"], qkv_bias=True,
            use_rel_pos=True, global_attn_indexes=tuple(a["global_attn_indexes"]),
            window_size=a["window_size"], out_chans=a["out_chans"]),
        prompt_encoder=m.PromptEncoder(
            embed_dim=a["out_chans"], image_embedding_size=(grid, grid),
            input_image_size=(a["img_size"], a["img_size"]), mask_in_chans=a["mask_in_chans"]),
        mask_decoder=m.MaskDecoder(
            num_multimask_outputs=a["num_multimask_outputs"],
            transformer=m.TwoWayTransformer(depth=a["decoder_depth"],
                                            embedding_dim=a["decoder_dim"],
                                            mlp_dim=a["decoder_mlp_dim"],
                                            num_heads=a["decoder_heads"]),
            transformer_dim=a["decoder_dim"], iou_head_depth=a["iou_head_depth"],
            iou_head_hidden_dim=a["iou_head_hidden_dim"]),
        pixel_mean=[123.675, 116.28, 103.53], pixel_std=[58.395, 57.12, 57.375])
    return sam.eval()


def LoadSam(path: str | Path, model_type: str = "auto", device: str = "cpu"):
    """The SAM stored at ``path`` (an official checkpoint or any state dict
    of the same modules; tensors only, never unpickled objects). With
    ``model_type`` vit_h / vit_l / vit_b the checkpoint must be that model."""
    path = Path(path)
    try:
        sd = torch.load(str(path), map_location="cpu", weights_only=True)
        if isinstance(sd, dict) and "model" in sd and isinstance(sd["model"], dict):
            sd = sd["model"]
        arch = SamArchitecture(sd)
    except (pickle.UnpicklingError, RuntimeError, EOFError, OSError) as err:
        raise MissingWeightsError(f"could not read the SAM checkpoint {path} "
                                  f"(perception.sam_checkpoint): {type(err).__name__}: "
                                  f"{' '.join(str(err).split())[:160]}") from None
    except (KeyError, ValueError, IndexError, TypeError, AttributeError) as err:
        raise MissingWeightsError(f"{path} (perception.sam_checkpoint) is not a SAM "
                                  f"(segment_anything) checkpoint: {type(err).__name__}: "
                                  f"{err}") from None
    if model_type in SAM_TYPES and SAM_TYPES[model_type] != (arch["embed_dim"], arch["depth"]):
        raise MissingWeightsError(
            f"{path} (perception.sam_checkpoint) holds a ViT of width {arch['embed_dim']} and "
            f"depth {arch['depth']}, not {model_type} (perception.sam_model_type); set "
            f"sam_model_type to the checkpoint's model or to auto")
    sam = BuildSam(arch)
    sam.load_state_dict(sd)
    sam.arch = arch
    return sam.to(device)


@torch.no_grad()
def SamMasks(sam, rgb: np.ndarray, boxes: np.ndarray, points: np.ndarray | None = None):
    """SAM's single-output masks for N prompts on one image: ``rgb`` HxWx3
    uint8, ``boxes`` (N, 4) pixel x0, y0, x1, y1, ``points`` (N, 2) pixel x,
    y foreground points or None. Returns (N, H, W) bool masks and (N,)
    predicted IoUs. The image is resized (longest side to the encoder's
    size, bilinear) and padded as ``segment_anything``'s predictor does."""
    H, W = rgb.shape[:2]
    S = sam.image_encoder.img_size
    scale = S / max(H, W)
    nh, nw = int(H * scale + 0.5), int(W * scale + 0.5)
    im = np.asarray(Image.fromarray(rgb).resize((nw, nh), Image.BILINEAR))
    dev = sam.device
    x = torch.as_tensor(np.array(im), device=dev).permute(2, 0, 1)[None].float()
    emb = sam.image_encoder(sam.preprocess(x))
    f = torch.tensor([nw / W, nh / H, nw / W, nh / H], dtype=torch.float32, device=dev)
    b = torch.as_tensor(np.asarray(boxes, np.float32), device=dev) * f
    pts = None
    if points is not None:
        p = torch.as_tensor(np.asarray(points, np.float32), device=dev) * f[:2]
        pts = (p[:, None, :], torch.ones((len(p), 1), dtype=torch.int, device=dev))
    sparse, dense = sam.prompt_encoder(points=pts, boxes=b, masks=None)
    low, iou = sam.mask_decoder(image_embeddings=emb, image_pe=sam.prompt_encoder.get_dense_pe(),
                                sparse_prompt_embeddings=sparse,
                                dense_prompt_embeddings=dense, multimask_output=False)
    masks = sam.postprocess_masks(low, (nh, nw), (H, W)) > sam.mask_threshold
    return masks[:, 0].cpu().numpy(), iou[:, 0].cpu().numpy()


@dc.dataclass
class Prompt:
    """One instance of the prompting segmentation: class id, its instance
    index there, box (x0, y0, x1, y1 px), innermost point (x, y px) and
    confidence."""
    class_id: int
    instance: int
    box: np.ndarray
    point: np.ndarray
    confidence: float


def PromptsFromSegmentation(seg: Segmentation, min_pixels: int = 30) -> list[Prompt]:
    """A prompt per branch, leaf and fruit instance of ``seg`` with at least
    ``min_pixels`` pixels."""
    out = []
    for c in (BRANCH, LEAF, FRUIT):
        m = seg.class_map == c
        ids, counts = np.unique(seg.instance_map[m], return_counts=True)
        for i, n in zip(ids, counts):
            if i < 0 or n < min_pixels:
                continue
            inst = m & (seg.instance_map == i)
            ys, xs = np.nonzero(inst)
            y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
            dist = ndimage.distance_transform_edt(np.pad(inst[y0:y1, x0:x1], 1))[1:-1, 1:-1]
            py, px = np.unravel_index(np.argmax(dist), dist.shape)
            out.append(Prompt(c, int(i), np.array([x0, y0, x1, y1], float),
                              np.array([x0 + px + 0.5, y0 + py + 0.5]),
                              float(seg.confidence.get((c, int(i)), 1.0))))
    return out


def ComposePromptedMasks(masks: np.ndarray, prompts: list[Prompt],
                         scores: np.ndarray) -> Segmentation:
    """Masks (N, H, W) of N prompts -> class and instance maps: larger masks
    painted first so smaller (usually nearer: a fruit seen through leaves)
    ones stay on top; instances renumbered per class by visible size (0 =
    largest); a mask left with no visible pixel is dropped. Confidence:
    clip(score, 0, 1) times the prompt's."""
    N = len(prompts)
    shape = masks.shape[1:]
    owner = np.full(shape, -1, np.int64)
    for k in np.argsort(-masks.reshape(N, -1).sum(axis=1), kind="stable"):
        owner[masks[k]] = k
    cls = np.zeros(shape, np.int64)
    inst = np.full(shape, -1, np.int64)
    conf = {}
    visible = np.bincount(owner[owner >= 0], minlength=N)
    for c in (BRANCH, LEAF, FRUIT):
        ks = [k for k in range(N) if prompts[k].class_id == c and visible[k] > 0]
        for j, k in enumerate(sorted(ks, key=lambda k: -visible[k])):
            sel = owner == k
            cls[sel], inst[sel] = c, j
            conf[(c, j)] = round(float(np.clip(scores[k], 0.0, 1.0)) * prompts[k].confidence, 4)
    return Segmentation(cls, inst, [], conf)


class SamSegmenter(Segmenter):
    """SAM prompted by another backend's instances (module docstring).
    Pixels beyond the depth cut are blacked out before SAM sees the image
    and are background (paper Sec. III-A-1)."""
    name = "sam"

    def __init__(self, cfg, K: Intrinsics, prompter: Segmenter | None = None):
        from lmap_drake.perception.segmentation import MakeSegmenter  # cycle: it makes this
        CheckSamPackage()
        path = SamCheckpointPath(cfg)
        if prompter is None and cfg.sam_prompts in ("sam", "grounded_sam"):
            raise SegmenterError(f"perception.sam_prompts '{cfg.sam_prompts}': SAM's prompts "
                                 f"come from segnet, color_depth or label")
        self.cfg = cfg
        self.prompter = prompter or MakeSegmenter(dc.replace(cfg, segmenter=cfg.sam_prompts), K)
        self.sam = LoadSam(path, cfg.sam_model_type, cfg.sam_device)

    def Segment(self, rgb, depth, label=None) -> Segmentation:
        rgb = _rgb3(rgb)
        d = _depth2(depth)
        valid = ValidDepthMask(d, self.cfg.depth_cut)
        prompts = PromptsFromSegmentation(self.prompter.Segment(rgb, d, label),
                                          self.cfg.sam_min_prompt_pixels)
        if not prompts:
            return Segmentation(np.zeros(d.shape, np.int64), np.full(d.shape, -1, np.int64),
                                ["no_prompts"])
        img = rgb.copy()
        img[~valid] = 0
        masks, scores = SamMasks(self.sam, img, np.stack([p.box for p in prompts]),
                                 np.stack([p.point for p in prompts]))
        return ComposePromptedMasks(masks & valid, prompts, scores)


# ----------------------------------------------------------------------------
# GroundedSAM adapter.

GROUNDED_SAM_PROMPT = "branch. leaf. sweet pepper."


def PhraseToClass(phrase: str) -> int:
    """GroundingDINO phrase -> class id (BACKGROUND when unrecognised)."""
    p = phrase.lower()
    if "pepper" in p or "sweet" in p or "fruit" in p:
        return FRUIT
    if "leaf" in p or "leaves" in p:
        return LEAF
    if "branch" in p or "stem" in p:
        return BRANCH
    return BACKGROUND


def BoxNms(boxes_xyxy: np.ndarray, scores: np.ndarray, iou_threshold: float) -> np.ndarray:
    """Indices kept by greedy non-maximum suppression, best score first."""
    boxes = np.asarray(boxes_xyxy, float).reshape(-1, 4)
    order = list(np.argsort(-np.asarray(scores, float), kind="stable"))
    area = (boxes[:, 2] - boxes[:, 0]).clip(0) * (boxes[:, 3] - boxes[:, 1]).clip(0)
    keep = []
    while order:
        i = order.pop(0)
        keep.append(i)
        rest = []
        for j in order:
            xx1, yy1 = max(boxes[i, 0], boxes[j, 0]), max(boxes[i, 1], boxes[j, 1])
            xx2, yy2 = min(boxes[i, 2], boxes[j, 2]), min(boxes[i, 3], boxes[j, 3])
            inter = max(0.0, xx2 - xx1) * max(0.0, yy2 - yy1)
            iou = inter / max(area[i] + area[j] - inter, 1e-12)
            if iou <= iou_threshold:
                rest.append(j)
        order = rest
    return np.asarray(keep, dtype=np.int64)


def ComposeMasks(masks: np.ndarray, phrases: list[str], shape,
                 scores: np.ndarray | None = None) -> Segmentation:
    """Instance masks (N, H, W) with phrases (and scores, default 1) ->
    class and instance maps (``ComposePromptedMasks``); unrecognised
    phrases are dropped."""
    masks = np.asarray(masks, bool).reshape(-1, *shape)
    scores = np.ones(len(masks)) if scores is None else np.asarray(scores, float)
    keep = [k for k in range(len(masks)) if PhraseToClass(phrases[k]) != BACKGROUND]
    prompts = [Prompt(PhraseToClass(phrases[k]), k, np.zeros(4), np.zeros(2), 1.0)
               for k in keep]
    if not keep:
        return Segmentation(np.zeros(shape, np.int64), np.full(shape, -1, np.int64))
    return ComposePromptedMasks(masks[keep], prompts, scores[keep])


class GroundedSamSegmenter(Segmenter):
    """GroundingDINO (text-prompted boxes) + SAM (box-prompted masks) with
    local weights. Pixels beyond ``depth_cut`` are blacked out before the
    models see the image (paper Sec. III-A-1). Instance confidence:
    GroundingDINO's box score times SAM's predicted IoU."""
    name = "grounded_sam"

    FILES = (("grounded_sam_config", "GroundingDINO model config (.py)"),
             ("grounded_sam_checkpoint", "GroundingDINO checkpoint (.pth)"),
             ("sam_checkpoint", "SAM checkpoint (.pth)"))

    def __init__(self, cfg):
        self.cfg = cfg
        for key, what in self.FILES:
            path = getattr(cfg, key, "")
            if not path:
                raise MissingWeightsError(
                    f"grounded_sam segmenter: perception.{key} is not set; it must name the "
                    f"local {what}. Nothing is downloaded: put the file on disk and set "
                    f"the key, or use segmenter: color_depth.")
            if not Path(path).is_file():
                raise MissingWeightsError(
                    f"grounded_sam segmenter: {what} not found at '{path}' "
                    f"(perception.{key}). Nothing is downloaded: put the file there, or "
                    f"use segmenter: color_depth.")
        if importlib.util.find_spec("groundingdino") is None:
            raise FoundationPackageError(
                "grounded_sam segmenter (perception.segmenter): the package 'groundingdino' "
                "is not installed (it needs torchvision, which does not install beside this "
                "project's CPU torch); use segmenter: sam (SAM prompted by segnet)")
        CheckSamPackage("grounded_sam")
        self._dino = None
        self._sam = None

    def _load(self):
        if self._dino is not None:
            return
        from groundingdino.util.inference import load_model
        c = self.cfg
        self._dino = load_model(c.grounded_sam_config, c.grounded_sam_checkpoint,
                                device=c.grounded_sam_device)
        self._sam = LoadSam(c.sam_checkpoint, c.sam_model_type, c.grounded_sam_device)

    def Segment(self, rgb, depth, label=None) -> Segmentation:
        self._load()
        import groundingdino.datasets.transforms as T
        from groundingdino.util.inference import predict
        c = self.cfg
        img = _rgb3(rgb).copy()
        d = _depth2(depth)
        img[~ValidDepthMask(d, c.depth_cut)] = 0
        H, W = img.shape[:2]
        transform = T.Compose([T.RandomResize([800], max_size=1333), T.ToTensor(),
                               T.Normalize([0.485, 0.456, 0.406], [0.229, 0.224, 0.225])])
        image_t, _ = transform(Image.fromarray(img), None)
        boxes, logits, phrases = predict(self._dino, image_t, GROUNDED_SAM_PROMPT,
                                         box_threshold=c.box_threshold,
                                         text_threshold=c.text_threshold,
                                         device=c.grounded_sam_device)
        if len(boxes) == 0:
            return Segmentation(np.zeros((H, W), np.int64), np.full((H, W), -1, np.int64),
                                ["no_detections"])
        b = boxes.cpu().numpy() * np.array([W, H, W, H])
        xyxy = np.stack([b[:, 0] - b[:, 2] / 2, b[:, 1] - b[:, 3] / 2,
                         b[:, 0] + b[:, 2] / 2, b[:, 1] + b[:, 3] / 2], axis=1)
        box_scores = logits.cpu().numpy()
        keep = BoxNms(xyxy, box_scores, c.nms_threshold)
        masks, iou = SamMasks(self._sam, img, xyxy[keep])
        return ComposeMasks(masks, [phrases[i] for i in keep], (H, W),
                            np.clip(iou, 0, 1) * box_scores[keep])
