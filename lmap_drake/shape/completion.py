"""The shape-completion stage as one function: SemanticScene -> SceneEstimate
(world frame W, metres). Branch completion, free space around the fruit
(carved along the rays to the observed points and the background ray ends),
then SSC (or a baseline) on the largest fruit instance.
"""
from __future__ import annotations

import time

import numpy as np

from lmap_drake.shape.baselines import FitHoma, FitSuperellipsoid
from lmap_drake.shape.branch import BranchCompletionParams, CompleteBranches
from lmap_drake.shape.free_space import FreeSpacePoints
from lmap_drake.shape.ssc import OptimizeShape, SscParams
from lmap_drake.types import SceneEstimate, SemanticScene

METHODS = ("ssc", "homa", "supeps")


def LargestInstance(points: np.ndarray, instance: np.ndarray) -> np.ndarray:
    """Points of the most populous instance id >= 0 (all points if none)."""
    if len(points) == 0 or instance is None or len(instance) != len(points):
        return points
    ids, counts = np.unique(instance[instance >= 0], return_counts=True)
    if len(ids) == 0:
        return points
    return points[instance == ids[np.argmax(counts)]]


def CompleteScene(semantic: SemanticScene, decoder=None, mean_latent=None,
                  params: SscParams | None = None, method: str = "ssc",
                  free_space_voxel: float = 0.003,
                  branch_params: BranchCompletionParams | None = None,
                  timings: dict | None = None) -> SceneEstimate:
    """Runs branch completion and fruit shape completion.

    ``method``: ``ssc`` (scene-consistent), ``homa`` (surface + reg only) or
    ``supeps`` (superellipsoid). ``params`` carries the SSC weights (use
    ``SscParams.FromConfig(cfg, reestimate=True)`` after the action).
    ``timings`` (optional dict) receives seconds per step."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    P = params or SscParams()
    timings = {} if timings is None else timings
    cam = np.asarray(semantic.X_WC, float)[:3, 3]
    out = SceneEstimate(semantic=semantic)
    t0 = time.time()
    if len(semantic.branch_points_W) >= 10:
        out.branch = CompleteBranches(semantic.branch_points_W, semantic.branch_instance, cam,
                                      branch_params)
    timings["branch_s"] = time.time() - t0
    fruit = LargestInstance(semantic.fruit_points_W, semantic.fruit_instance)
    if len(fruit) < 10 or "no_fruit_in_view" in semantic.flags:
        return out
    t0 = time.time()
    if method == "supeps":
        out.fruit = FitSuperellipsoid(fruit, cam, seed=P.seed)
    elif method == "homa":
        out.fruit = FitHoma(decoder, mean_latent, fruit, cam, P)
    else:
        observed = [p for p in (semantic.fruit_points_W, semantic.leaf_points_W,
                                semantic.branch_points_W, semantic.background_points_W)
                    if len(p)]
        free = FreeSpacePoints(cam, np.vstack(observed), fruit, free_space_voxel)
        timings["free_space_s"] = time.time() - t0
        negatives = [(semantic.leaf_points_W, 1.0), (semantic.branch_points_W, 1.0),
                     (free, 1.0)]
        samples = None
        if out.branch is not None:
            samples = out.branch.samples_W
            negatives.append((samples, P.w_neg_completed_branch))
        out.fruit = OptimizeShape(decoder, mean_latent, fruit, cam, negatives, samples, P)
    timings["fruit_s"] = time.time() - t0
    return out
