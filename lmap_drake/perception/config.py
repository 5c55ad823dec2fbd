"""Configuration of perception (segmentation, point clouds, view fusion,
free space): the ``perception`` section of the scenario. Lengths in metres."""
# (no ``from __future__ import annotations``: Drake's ``yaml_load_typed``
# reads the field types)

import dataclasses as dc
import importlib.util
from pathlib import Path

from lmap_drake.config_checks import CheckRules
from lmap_drake.errors import ConfigError
from lmap_drake.paths import REPO_ROOT


@dc.dataclass
class PerceptionConfig:
    """Segmentation and point-cloud parameters (paper Sec. III-A-1). See
    ``lmap_drake/perception/``. Lengths in metres."""
    # segnet (the default: trained RGB-D network, no labels) | color_depth
    # (classical colour + depth) | label (the simulator's labels: an oracle
    # for ablations) | sam (SAM prompted by sam_prompts' instances, local
    # checkpoint, extra .[foundation]) | grounded_sam (local GroundingDINO + SAM files)
    segmenter: str = "segnet"
    # segnet: weights (relative to the repository root; made by
    # scripts/train_segnet.py) and torch device.
    segnet_weights: str = "models/segnet/segnet.pt"
    segnet_device: str = "cpu"  # segnet: torch device ("cpu", "cuda", ...)
    depth_cut: float = 1.5  # m: pixels deeper (camera z) are not segmented or turned into points
    dbscan_eps: float = 0.008  # m, DBSCAN neighbour radius that splits a class into instances
    # DBSCAN: points a core point needs within dbscan_eps; fewer = noise (no instance)
    dbscan_min_points: int = 15
    # Cut leaf clusters along the segmenter's leaf boundaries (label: the
    # render's leaf ids; segnet: its boundary head): flush blades that one
    # DBSCAN cluster joins (perception/leaf_boundaries.py). false: the ablation.
    leaf_boundaries: bool = True
    # segnet: a fruit instance lying in a leaf's surface (its border mostly
    # leaf continuing its depth: a phantom) gets confidence 0, so it is no
    # target but stays an obstacle (leaf_patches.VetoLeafPatches). false: the ablation.
    fruit_leaf_patches: bool = True
    # segnet: a fruit instance of fewer pixels, farther than a fruit's length
    # from every larger one, is called its pixels' next most probable class (no
    # fruit is completed from fewer points than shape.min_fruit_points; 0 = keep
    # every one; perception/fruit_fragments.py, docs/how-to/train-segmenter.md)
    min_fruit_pixels: int = 20
    # label: the greenhouse's neighbouring plants as leaf / branch (what the
    # camera sees, and what an arm must keep clear of in a real row) or, false,
    # as background (labels.OracleLabels; docs/how-to/greenhouse-suite.md)
    label_neighbours: bool = True
    # m, voxel of the downsampled class clouds (per instance) and of view fusion
    voxel_size: float = 0.003
    # Statistical outlier removal (open3d): neighbours and std-dev ratio.
    outlier_neighbors: int = 20
    # Outlier removal: a point whose mean neighbour distance exceeds the cloud's
    # mean by this many standard deviations is dropped.
    outlier_std_ratio: float = 2.0
    # color_depth: structures narrower than this are branch candidates; green
    # curved regions may be reported as (green) fruit.
    branch_max_width: float = 0.035
    detect_green_fruit: bool = True  # color_depth: report green curved regions as (green) fruit
    # grounded_sam: local files only (GroundingDINO config .py and checkpoint,
    # SAM checkpoint), never downloaded; SAM model type; torch device.
    grounded_sam_config: str = ""
    grounded_sam_checkpoint: str = ""  # grounded_sam: GroundingDINO checkpoint (.pth)
    # sam, grounded_sam: SAM checkpoint (.pth, e.g. sam_vit_b_01ec64.pth;
    # relative to the repository root unless absolute), never downloaded
    sam_checkpoint: str = ""
    # sam, grounded_sam: the checkpoint's model, vit_h | vit_l | vit_b, or auto
    # (any SAM configuration: read from the checkpoint)
    sam_model_type: str = "vit_h"
    # sam: the backend whose instances prompt SAM, segnet | color_depth | label
    sam_prompts: str = "segnet"
    sam_device: str = "cpu"  # sam: torch device of SAM ("cpu", "cuda", ...)
    sam_min_prompt_pixels: int = 30  # sam: smaller prompting instances are not given to SAM
    grounded_sam_device: str = "cpu"  # grounded_sam: torch device of both models
    box_threshold: float = 0.25  # grounded_sam: GroundingDINO box score threshold, [0, 1]
    text_threshold: float = 0.25  # grounded_sam: GroundingDINO text (phrase) threshold, [0, 1]
    nms_threshold: float = 0.8  # grounded_sam: IoU above which overlapping boxes are suppressed
    # view fusion: a new instance joins an earlier one within this distance.
    fusion_match_distance: float = 0.008
    # Free space from background pixels (every ``background_stride``-th
    # pixel per row and column): their rays passed the plant. A +inf depth
    # (no return) is taken as nothing within ``no_return_free_range`` m
    # (0 = such pixels carve nothing). Right for the simulated camera; on
    # hardware set it to 0: the RealSense client also maps dropouts (dark or
    # glancing surfaces, too close) to +inf, and those would carve the fruit.
    background_stride: int = 2
    # m: a no-return (+inf) pixel's ray is free this far (0 = carves nothing; hardware: 0)
    no_return_free_range: float = 2.0
    # ... but only where no pixel with a return lies within this many pixels:
    # a narrower no-return patch is a dropout (glancing rim, thin part,
    # speckle) next to a surface, not open space. The simulated camera's
    # dropouts (camera_noise) all lie within 2.83 px of a return (60k
    # dropout pixels in the 26 scenes of the three suites; fruit 1.4 px,
    # leaf and branch 2.0); at 6 px the guard also withheld the 8 mm of free
    # space beside every silhouette, and fits bulged sideways into it.
    no_return_margin_px: float = 3.0
    # Flying pixels (depth between a nearer and a farther neighbour, each
    # more than this apart, m; 0 = keep all) are dropped before
    # de-projection: they float in the gap between a leaf and the fruit.
    flying_pixel_jump: float = 0.005
    # Robot self-filter: plant points within this distance (m) of the robot's
    # collision surfaces at the view's joints are dropped (a gripper pixel
    # mislabelled leaf, fruit or branch is not plant; 0 = keep all).
    robot_filter_distance: float = 0.01
    # Robot mask: before instances are built, the pixels the robot covers at
    # the view's joints (its visual geometry rendered by Drake's
    # RenderEngineVtk at the camera's intrinsics and pose; joints from the
    # station, ur_rtde on hardware) are set to background, unless the
    # measured depth there is nearer than the robot by more than
    # ``robot_mask_tolerance`` (plant in front of the robot).
    robot_mask: bool = True
    robot_mask_tolerance: float = 0.01  # m: plant nearer than the robot by more keeps its pixels
    # pixels the robot mask is grown by (the depth camera's edge noise at the robot's rim)
    robot_mask_dilate_px: int = 1



_RULES = {
    "depth_cut": ">0",
    "dbscan_eps": ">0",
    "dbscan_min_points": ">=1",
    "min_fruit_pixels": ">=0",
    "voxel_size": ">0",
    "outlier_neighbors": ">=1",
    "outlier_std_ratio": ">0",
    "branch_max_width": ">0",
    "box_threshold": "[0,1]",
    "text_threshold": "[0,1]",
    "nms_threshold": "[0,1]",
    "sam_min_prompt_pixels": ">=1",
    "fusion_match_distance": ">=0",
    "robot_filter_distance": ">=0",
    "robot_mask_tolerance": ">=0",
    "robot_mask_dilate_px": ">=0",
    "background_stride": ">=1",
    "no_return_free_range": ">=0",
    "no_return_margin_px": ">=0",
    "flying_pixel_jump": ">=0",
}
_ENUMS = {
    "segmenter": ("segnet", "color_depth", "label", "sam", "grounded_sam"),  # SEGMENTERS
    "sam_model_type": ("vit_h", "vit_l", "vit_b", "auto"),
    "sam_prompts": ("segnet", "color_depth", "label"),
}


def ValidatePerceptionConfig(cfg: PerceptionConfig, path: str = "perception") -> None:
    """Raises ``ConfigError`` (key path, what is wrong) on a bad value; for
    ``segmenter: sam`` also when the SAM checkpoint or package is missing."""
    CheckRules(cfg, path, _RULES, _ENUMS)
    if cfg.segmenter == "sam":
        if not cfg.sam_checkpoint:
            raise ConfigError(f"{path}.sam_checkpoint", "must name the local SAM checkpoint "
                              "(.pth) for segmenter: sam; nothing is downloaded (see "
                              "docs/how-to/foundation-segmenter.md)")
        file = Path(cfg.sam_checkpoint)
        file = file if file.is_absolute() else REPO_ROOT / file
        if not file.is_file():
            raise ConfigError(f"{path}.sam_checkpoint", f"no file at {file}; nothing is "
                              "downloaded (see docs/how-to/foundation-segmenter.md)")
        if importlib.util.find_spec("segment_anything") is None:
            raise ConfigError(f"{path}.segmenter", "sam needs the package 'segment_anything' "
                              "(not installed): pip install -e '.[foundation]'")
