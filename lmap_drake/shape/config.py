"""Configuration of shape completion (paper Sec. III-A): the ``shape``
section of the scenario, with the fruit fit in ``shape.ssc`` (``SscConfig``,
``lmap_drake/shape/ssc.py``) and the branch completion in ``shape.branch``
(``BranchCompletionConfig``, ``lmap_drake/shape/branch.py``). Lengths in
metres unless a name says otherwise."""
# (no ``from __future__ import annotations``: Drake's ``yaml_load_typed``
# reads the field types)

import dataclasses as dc

from lmap_drake.config_checks import CheckRules, Need


@dc.dataclass
class SscConfig:
    """Scene-consistent shape completion of a fruit (and the HoMa-style
    baseline, which uses the same optimiser); see ``lmap_drake/shape/ssc.py``.

    Losses measure lengths in ``loss_length_unit`` (m; 0.01 = cm).
    ``peduncle_huber`` (m), ``peduncle_moves_scale``,
    ``peduncle_follow_axis``, ``peduncle_slide``, ``peduncle_base_distance``
    (m): the robust peduncle term. ``init_from_observation`` /
    ``init_scale_bounds``: the start scale and centre from the observed
    points. ``rotation_lr_scale``: the rotation's share of the Adam step;
    ``rotation_hold_steps``: the first estimate keeps the rotation still for
    this many Adam steps, 0 = off; ``w_rot``: the pull toward upright, 0 =
    off. ``surface_sampling``: spread (farthest-point) or random choice of
    the ``max_surface_points``; ``stop_tolerance`` / ``min_iterations``:
    the fit stops early when the loss flattens (0 = never).
    ``num_hypotheses`` and ``hypothesis_*``: the set of plausible shapes
    fitted besides the estimate (``lmap_drake/shape/hypotheses.py``; 0 =
    none). ``reestimate_*``: the same weights for the re-estimate after the
    action (``ReestimateConfig``). ``fruit_volume_cm3``: the typical volume
    of the variety (cm^3; 0 = the template's own mean shape, about 170
    cm^3): every SSC and HoMa-style fit starts at the template scaled to it
    (``shape.ssc.PriorScale``). With a tenth of a fruit in view the fitted
    size stays near the start, so a lab that knows its variety should set it
    (see the README's *Your own pepper mesh*). ``seed``: the random
    subsampling of the points."""
    w_sur: float = 1.0  # weight of the surface loss (fruit points on the fitted surface)
    w_neg: float = 2.0  # weight of the negative loss (leaf, branch, free space kept outside)
    w_ped: float = 0.1  # weight of the peduncle loss (fruit top to the completed branch); 0 = off
    w_reg: float = 1.0  # weight of the latent regulariser |z|^2
    # weight of the completed-branch samples among the negatives (the others weigh 1)
    w_neg_completed_branch: float = 0.1
    learning_rate: float = 0.01  # Adam step size (latent, log scale, translation)
    iterations: int = 300  # Adam steps of one fit
    num_peduncle_points: int = 10  # template points at the fruit top used by the peduncle loss
    loss_length_unit: float = 0.01
    # m: the fit starts at the fruit points' centroid moved this far away from the
    # camera (unless ``init_from_observation``)
    push_from_camera: float = 0.01
    max_surface_points: int = 100  # fruit points used by the surface loss (``surface_sampling``)
    max_negative_points: int = 200  # cap on the active negative points per refresh
    # m: negatives inside or within this of the current surface are active
    negative_margin: float = 0.005
    # negatives examined per refresh (random subset of those near the start centre)
    max_negative_candidates: int = 4000
    # m: peduncle pairs (template top point, branch sample) farther apart are left out
    peduncle_max_distance: float = 0.02
    # deg: a branch sample pairs only within this angle of the fruit axis, seen from the centre
    peduncle_cone_deg: float = 30.0
    peduncle_huber: float = 0.005
    peduncle_moves_scale: bool = False
    peduncle_follow_axis: bool = False
    peduncle_slide: bool = True
    peduncle_base_distance: float = 0.01
    init_from_observation: bool = False
    fruit_volume_cm3: float = 0.0
    rotation_lr_scale: float = 0.3
    rotation_hold_steps: int = 50
    w_rot: float = 0.0
    init_scale_bounds: list[float] = dc.field(default_factory=lambda: [0.5, 2.0])
    refresh_every: int = 25  # iterations between re-selections of active negatives, peduncle pairs
    mesh_spacing: float = 0.003  # m, grid spacing of the fitted fruit's output mesh
    reestimate_w_ped: float = 0.01
    reestimate_w_neg_completed_branch: float = 0.01
    reestimate_rotation_lr_scale: float = 1.0
    reestimate_w_rot: float = 0.0
    reestimate_rotation_hold_steps: int = 50
    surface_sampling: str = "random"  # random | spread (farthest-point) choice of them
    # stop when the loss falls by less than this fraction per refresh window; 0 = off
    stop_tolerance: float = 0.0
    min_iterations: int = 100  # Adam steps before ``stop_tolerance`` may stop the fit
    # shape hypotheses fitted per fruit (the estimate among them); 0 = none
    num_hypotheses: int = 6
    hypothesis_iterations: int = 100  # Adam steps of the batched hypothesis fit
    hypothesis_surface_points: int = 48  # fruit points (spread) per hypothesis
    hypothesis_negative_points: int = 48  # cap on the active negatives per hypothesis
    hypothesis_negative_candidates: int = 1500  # negatives examined per refresh (shared)
    # factors on the estimate's scale of the hypotheses' starts (log-spaced)
    hypothesis_scale_range: list[float] = dc.field(default_factory=lambda: [0.7, 1.4])
    hypothesis_tilt_deg: float = 15.0  # deg: the starts' axes tilted this far from the estimate's
    # m: kept if its RMS surface residual is within this of the best one's
    hypothesis_margin: float = 0.0005
    hypothesis_inlier_distance: float = 0.002  # m: a fruit point this near the surface is explained
    hypothesis_min_inliers: float = 0.9  # kept if this fraction of the fruit points is explained
    hypothesis_max_inside: float = 0.02  # dropped if more of the negatives are 2 mm inside it
    hypothesis_mesh_spacing: float = 0.005  # m: grid spacing of each hypothesis's mesh
    seed: int = 0


def ReestimateConfig(cfg: SscConfig) -> SscConfig:
    """``cfg`` with its ``reestimate_*`` weights in place of the first
    estimate's (the re-estimate after the leaf action)."""
    return dc.replace(cfg, w_ped=cfg.reestimate_w_ped,
                      w_neg_completed_branch=cfg.reestimate_w_neg_completed_branch,
                      rotation_lr_scale=cfg.reestimate_rotation_lr_scale,
                      w_rot=cfg.reestimate_w_rot,
                      rotation_hold_steps=cfg.reestimate_rotation_hold_steps)


@dc.dataclass
class BranchCompletionConfig:
    """Branch completion (``lmap_drake/shape/branch.py``): ``slab`` (m)
    thickness of the circle-fit slabs, ``radius_factor`` on the fitted
    radius, ``mesh_res`` (m) cylinder mesh edges, ``match_distance`` (m)
    point-vertex matches of the ARAP fit, whose handles pull with
    ``handle_weight`` for at most ``max_iterations`` until the energy falls
    by less than ``relative_tolerance``; ``sample_spacing`` (m) surface
    samples of the completed mesh."""
    slab: float = 0.01
    radius_factor: float = 1.0
    mesh_res: float = 0.003
    match_distance: float = 0.03
    handle_weight: float = 10.0
    max_iterations: int = 30
    relative_tolerance: float = 1e-4
    sample_spacing: float = 0.002


@dc.dataclass
class ShapeConfig:
    """Branch completion and scene-consistent shape completion (Sec. III-A).

    ``weights_file`` is relative to the repository root (written by
    ``scripts/train_deepsdf.py``); ``mean_latent_file`` is only needed for a
    HortiMapping-style checkpoint. ``method``: ssc | homa | supeps; the fruit
    fit's settings are ``ssc``, the branch's ``branch``.
    ``leaf_split_angle_deg`` (plants with several fruits): touching leaves
    (one cluster of points) are told apart where their surfaces meet at more
    than this angle (``perception.points.SplitTouchingLeaves``; 0 = leaf
    instances as clustered). ``reuse_tolerance`` (m; plants with several
    fruits): a fruit whose points and surroundings in a new view match an
    earlier fit's within this distance (95 % of the points both ways, the
    sensor's noise between two captures) keeps that fit instead of a new
    one (``shape.completion.FitMemo``; 0 = always fit again).
    ``min_fruit_points`` (plants with several fruits): the smallest fruit
    instance completed, in voxels of ``perception.voxel_size`` (20 at 3 mm:
    1.8 cm², about 5 % of a 7 cm pepper's outline; measured with
    ``scripts/eval_fruit_detection.py``)."""
    weights_file: str = "models/deepsdf/pepper_decoder.pt"
    mean_latent_file: str = ""
    method: str = "ssc"
    # Informational, not read by the pipeline: the decoder's latent size comes from
    # ``weights_file`` (the shipped one: 32; ``scripts/train_deepsdf.py --latent_size``).
    latent_size: int = 32
    free_space_voxel: float = 0.003  # m, voxel of the ray-carved free space (SSC negatives)
    leaf_split_angle_deg: float = 15.0
    reuse_tolerance: float = 0.005
    min_fruit_points: int = 20
    ssc: SscConfig = dc.field(default_factory=SscConfig)
    branch: BranchCompletionConfig = dc.field(default_factory=BranchCompletionConfig)


METHODS = ("ssc", "homa", "supeps")

_RULES = {
    "latent_size": ">=1",
    "free_space_voxel": ">0",
    "leaf_split_angle_deg": ">=0",
    "reuse_tolerance": ">=0",
    "min_fruit_points": ">=1",
    "ssc.w_sur": ">=0",
    "ssc.w_neg": ">=0",
    "ssc.w_ped": ">=0",
    "ssc.w_reg": ">=0",
    "ssc.w_neg_completed_branch": ">=0",
    "ssc.reestimate_w_ped": ">=0",
    "ssc.reestimate_w_neg_completed_branch": ">=0",
    "ssc.learning_rate": ">0",
    "ssc.iterations": ">=1",
    "ssc.num_peduncle_points": ">=1",
    "ssc.loss_length_unit": ">0",
    "ssc.max_surface_points": ">=1",
    "ssc.max_negative_points": ">=1",
    "ssc.negative_margin": ">=0",
    "ssc.max_negative_candidates": ">=1",
    "ssc.peduncle_max_distance": ">0",
    "ssc.peduncle_cone_deg": "(0,180]",
    "ssc.peduncle_huber": ">=0",
    "ssc.peduncle_base_distance": ">=0",
    "ssc.w_rot": ">=0",
    "ssc.rotation_lr_scale": ">0",
    "ssc.reestimate_rotation_lr_scale": ">0",
    "ssc.reestimate_w_rot": ">=0",
    "ssc.reestimate_rotation_hold_steps": ">=0",
    "ssc.rotation_hold_steps": ">=0",
    "ssc.init_scale_bounds": "2x>0",
    "ssc.refresh_every": ">=1",
    "ssc.mesh_spacing": ">0",
    "ssc.stop_tolerance": ">=0",
    "ssc.num_hypotheses": ">=0",
    "ssc.hypothesis_iterations": ">=1",
    "ssc.hypothesis_surface_points": ">=1",
    "ssc.hypothesis_negative_points": ">=1",
    "ssc.hypothesis_negative_candidates": ">=1",
    "ssc.hypothesis_scale_range": "2x>0",
    "ssc.hypothesis_tilt_deg": "[0,90]",
    "ssc.hypothesis_margin": ">=0",
    "ssc.hypothesis_inlier_distance": ">0",
    "ssc.hypothesis_min_inliers": "[0,1]",
    "ssc.hypothesis_max_inside": "[0,1]",
    "ssc.hypothesis_mesh_spacing": ">0",
    "ssc.min_iterations": ">=0",
    "branch.slab": ">0",
    "branch.radius_factor": ">0",
    "branch.mesh_res": ">0",
    "branch.match_distance": ">0",
    "branch.handle_weight": ">0",
    "branch.max_iterations": ">=1",
    "branch.relative_tolerance": ">0",
    "branch.sample_spacing": ">0",
}
_ENUMS = {"method": METHODS, "ssc.surface_sampling": ("random", "spread")}


def ValidateShapeConfig(cfg: ShapeConfig, path: str = "shape") -> None:
    """Raises ``ConfigError`` (key path, what is wrong) on a bad value."""
    CheckRules(cfg, path, _RULES, _ENUMS)
    Need(cfg.weights_file or cfg.method == "supeps", f"{path}.weights_file",
         "is empty; the ssc and homa methods need the DeepSDF weights")
    isb = cfg.ssc.init_scale_bounds
    Need(len(isb) != 2 or isb[0] <= isb[1], f"{path}.ssc.init_scale_bounds",
         f"must be [lower, upper] with lower <= upper, got {list(isb)}")
    fv = cfg.ssc.fruit_volume_cm3
    Need(fv == 0 or 5 <= fv <= 3000, f"{path}.ssc.fruit_volume_cm3",
         f"must be 0 (the template's own size) or a pepper's volume in cm^3 (5-3000), "
         f"got {fv} (a value in m^3 or mm^3?)")
