"""The shape-completion stage as one function: SemanticScene -> SceneEstimate
(world frame W, metres). Branch completion, free space around the fruit
(carved along the rays to the observed points and the background ray ends),
then SSC (or a baseline) on the largest fruit instance (``CompleteScene``) or
on every fruit instance (``CompletePlant``).
"""
from __future__ import annotations

import dataclasses as dc
import time

import numpy as np

from lmap_drake.parallel import ParallelMap
from lmap_drake.perception.leaf_instances import SplitLeafNecks
from lmap_drake.perception.points import SplitOversizedLeaves, SplitTouchingLeaves
from lmap_drake.shape.baselines import FitHoma, FitSuperellipsoid, HomaParams
from lmap_drake.shape.branch import CompleteBranches
from lmap_drake.shape.config import METHODS, BranchCompletionConfig, SscConfig
from lmap_drake.shape.free_space import FreeSpacePoints
from lmap_drake.shape.hypotheses import FitHypotheses
from lmap_drake.shape.ssc import OptimizeShape
from lmap_drake.types import PlantEstimate, SceneEstimate, SemanticScene

# Fragments whose points lie this close (m, median |SDF|) to another
# fragment's completed surface are one fruit (``CompletePlant``).
MERGE_DISTANCE = 0.006
# A merge stands only if the union's fit puts every fragment's points as
# close to its surface (median |SDF|) as the fragment's own fit did, within
# this (m): fragments of one fruit fit together (here +0.0-0.3 mm); a piece
# of stalk the segmenter took for fruit, 5 cm above the fruit's centre, does
# not (+1.0 mm: the union stretched the fruit to reach it, 2x its volume).
MERGE_RESIDUAL_TOLERANCE = 0.0005
# Only a fragment this small against the other (points) is dropped when the
# union does not hold it; two of comparable size are merged as before, since
# dropping either could lose a fruit (the pieces seen were 12-21 %).
DROP_FRACTION = 0.5
# Two fits whose centres are closer than this fraction of the sum of their
# mean radii are fragments of one fruit to try merging (``FruitsOverlap``).
MERGE_OVERLAP_FRACTION = 0.6
# Two real fruits cannot interpenetrate: their fits' centres lie at least
# the sum of their mean radii apart. On the first views of 24 multi-fruit
# plants (the suite and three random seeds, 70 fruit pairs) real
# neighbours' fits were 1.48 or more of that sum apart; the one phantom (a
# calyx and stalk top cut off from its fruit by a leaf, labelled fruit)
# completed to a fit 0.90 of it from its fruit's. A fragment under
# ``DROP_FRACTION`` of the other's points whose fit interpenetrates the
# other's, but neither lies on the other nor overlaps it as much as
# fragments of one fruit do, is not a fruit: dropped, never merged (a union
# of two partial caps can "hold" both, stretched: 123 cm^3 too large in
# one re-estimate).
OVERLAP_FRACTION = 1.0
# The scene flag of the fragments dropped (``DROPPED_FLAG:N``).
DROPPED_FLAG = "fruit_fragment_dropped"


def LargestInstance(points: np.ndarray, instance: np.ndarray) -> np.ndarray:
    """Points of the most populous instance id >= 0 (all points if none)."""
    if len(points) == 0 or instance is None or len(instance) != len(points):
        return points
    ids, counts = np.unique(instance[instance >= 0], return_counts=True)
    if len(ids) == 0:
        return points
    return points[instance == ids[np.argmax(counts)]]


def CompleteScene(semantic: SemanticScene, decoder=None, mean_latent=None,
                  params: SscConfig | None = None, method: str = "ssc",
                  free_space_voxel: float = 0.003,
                  branch_params: BranchCompletionConfig | None = None,
                  timings: dict | None = None) -> SceneEstimate:
    """Runs branch completion and fruit shape completion.

    ``method``: ``ssc`` (scene-consistent), ``homa`` (surface + reg only) or
    ``supeps`` (superellipsoid). ``params`` carries the SSC weights (use
    ``ReestimateConfig(cfg.ssc)`` after the action).
    ``timings`` (optional dict) receives seconds per step."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    P = params or SscConfig()
    timings = {} if timings is None else timings
    cam = np.asarray(semantic.X_WC, float)[:3, 3]
    out = SceneEstimate(semantic=semantic, branch=_Branches(semantic, cam, branch_params,
                                                            timings))
    fruit = LargestInstance(semantic.fruit_points_W, semantic.fruit_instance)
    if len(fruit) < 10 or "no_fruit_in_view" in semantic.flags:
        return out
    out.fruit = _CompleteFruit(semantic, fruit, np.zeros((0, 3)), out.branch, decoder,
                               mean_latent, P, method, free_space_voxel, timings)
    return out


def _Branches(semantic: SemanticScene, cam: np.ndarray, branch_params, timings: dict):
    """Every branch instance completed (None with fewer than 10 points)."""
    t0 = time.time()
    out = None
    if len(semantic.branch_points_W) >= 10:
        out = CompleteBranches(semantic.branch_points_W, semantic.branch_instance, cam,
                               branch_params)
    timings["branch_s"] = time.time() - t0
    return out


def _CompleteFruit(semantic: SemanticScene, fruit: np.ndarray, other_fruits: np.ndarray,
                   branch, decoder, mean_latent, P: SscConfig, method: str,
                   free_space_voxel: float, timings: dict):
    """One fruit's estimate from its points ``fruit``; ``other_fruits``
    (points of the plant's other fruits) are outside it, like the leaves."""
    cam = np.asarray(semantic.X_WC, float)[:3, 3]
    t0 = time.time()
    if method == "supeps":
        est = FitSuperellipsoid(fruit, cam, seed=P.seed)
    elif method == "homa":
        est = FitHoma(decoder, mean_latent, fruit, cam, P)
        if P.num_hypotheses > 0:       # the same set from the points alone
            t1 = time.time()
            est.hypotheses = FitHypotheses(decoder, mean_latent, fruit, cam, (),
                                           HomaParams(P), est)
            timings["hypotheses_s"] = timings.get("hypotheses_s", 0.0) + time.time() - t1
    else:
        observed = [p for p in (semantic.fruit_points_W, semantic.leaf_points_W,
                                semantic.branch_points_W, semantic.background_points_W)
                    if len(p)]
        free = FreeSpacePoints(cam, np.vstack(observed), fruit, free_space_voxel)
        timings["free_space_s"] = timings.get("free_space_s", 0.0) + time.time() - t0
        negatives = [(semantic.leaf_points_W, 1.0), (semantic.branch_points_W, 1.0),
                     (free, 1.0)]
        if len(other_fruits):
            negatives.append((other_fruits, 1.0))
        samples = None
        if branch is not None:
            samples = branch.samples_W
            negatives.append((samples, P.w_neg_completed_branch))
        est = OptimizeShape(decoder, mean_latent, fruit, cam, negatives, samples, P)
        if P.num_hypotheses > 0:
            t1 = time.time()
            est.hypotheses = FitHypotheses(decoder, mean_latent, fruit, cam, negatives, P, est)
            timings["hypotheses_s"] = timings.get("hypotheses_s", 0.0) + time.time() - t1
    timings["fruit_s"] = timings.get("fruit_s", 0.0) + time.time() - t0
    return est


@dc.dataclass
class FitMemo:
    """The fruit fits of one episode, kept so that a fruit seen again
    unchanged is not fitted again (``CompletePlant``): on a plant with
    several fruits every new view completes every fruit, and the fruits
    nobody touched are observed as before up to the sensor's noise.

    A fit is reused when the settings and the camera are the same, and
    both the fruit's points and every observed point within ``reach`` (m)
    of them (the other fruits, leaves, branches, background: what the
    free-space and negative losses see) match the earlier ones: at least
    ``fraction`` of each set lies within ``tolerance`` (m) of the other, both
    ways. Two captures of one still scene differ by the depth noise (1.5-2.6
    mm at 0.5-0.8 m, ``camera_noise``): 97-100 % of the points lie within 5
    mm; a leaf moved over the fruit or more of the fruit revealed breaks
    the match, and so do point counts more than ``count_ratio`` apart.
    Only fits of earlier views count (``NewView``): within one view two
    fragments and their union are different fits. ``tolerance`` 0 turns
    reuse off. Thread-safe for ``CompletePlant``'s workers (appends only)."""
    tolerance: float = 0.005
    fraction: float = 0.95
    count_ratio: float = 1.25
    reach: float = 0.12
    entries: list = dc.field(default_factory=list)
    view: int = 0

    def NewView(self) -> None:
        """Starts a view: fits added from now on are not reused within it."""
        self.view += 1

    def _Hood(self, semantic: SemanticScene, fruit: np.ndarray) -> np.ndarray:
        observed = np.vstack([np.asarray(p, float).reshape(-1, 3) for p in (
            semantic.fruit_points_W, semantic.leaf_points_W, semantic.branch_points_W,
            semantic.background_points_W)])
        lo, hi = fruit.min(axis=0) - self.reach, fruit.max(axis=0) + self.reach
        return observed[np.all((observed >= lo) & (observed <= hi), axis=1)]

    def _Same(self, a: np.ndarray, b: np.ndarray) -> bool:
        from scipy.spatial import cKDTree
        if len(a) == 0 or len(b) == 0:
            return len(a) == len(b)
        if max(len(a), len(b)) > self.count_ratio * min(len(a), len(b)):
            return False
        tol = self.tolerance
        return bool(np.mean(cKDTree(b).query(a, distance_upper_bound=tol)[0] < tol)
                    >= self.fraction and
                    np.mean(cKDTree(a).query(b, distance_upper_bound=tol)[0] < tol)
                    >= self.fraction)

    def Find(self, key: tuple, semantic: SemanticScene, fruit: np.ndarray):
        """(an earlier estimate for these points or None, the neighbourhood
        to ``Add`` with a new fit)."""
        if self.tolerance <= 0:
            return None, None
        hood = self._Hood(semantic, fruit)
        for view, k, f, h, est in list(self.entries):
            if view < self.view and k == key and self._Same(fruit, f) and self._Same(hood, h):
                return est, hood
        return None, hood

    def Add(self, key: tuple, fruit: np.ndarray, hood, estimate) -> None:
        if self.tolerance > 0 and hood is not None and estimate is not None:
            self.entries.append((self.view, key, fruit.copy(), hood, estimate))


def FruitInstances(semantic: SemanticScene, min_points: int = 30) -> list[int]:
    """Fruit instance ids with at least ``min_points`` points, largest first."""
    inst = np.asarray(semantic.fruit_instance)
    if len(inst) != len(semantic.fruit_points_W):
        return []
    ids, counts = np.unique(inst[inst >= 0], return_counts=True)
    order = np.argsort(-counts, kind="stable")
    return [int(ids[k]) for k in order if counts[k] >= min_points]


def CompletePlant(semantic: SemanticScene, decoder=None, mean_latent=None,
                  params: SscConfig | None = None, method: str = "ssc",
                  free_space_voxel: float = 0.003,
                  branch_params: BranchCompletionConfig | None = None,
                  min_fruit_points: int = 30, timings: dict | None = None,
                  merge_distance: float = MERGE_DISTANCE,
                  merge_tolerance: float = MERGE_RESIDUAL_TOLERANCE,
                  leaf_split_angle_deg: float = 15.0,
                  focus_W: np.ndarray | None = None,
                  focus_radius: float = 0.08, workers: int | None = None,
                  memo: FitMemo | None = None) -> PlantEstimate:
    """Every fruit instance (``FruitInstances``) completed on its own, the
    other fruits' points counted as outside it (paper Sec. III-F: one
    estimate per fruit), and the branches completed once. Fragments of one
    fruit (split by a leaf across it) are merged when one lies within
    ``merge_distance`` (m, median) of the other's completed surface, or when
    the two completed shapes overlap (``MERGE_OVERLAP_FRACTION``), and the
    union's fit holds both (``UnionExplains`` within ``merge_tolerance``);
    else a fragment under ``DROP_FRACTION`` of the other's points is dropped
    (instance -1, flag ``fruit_fragment_dropped``), as is one whose fit
    merely interpenetrates the other's (``OVERLAP_FRACTION``). Touching leaves are
    told apart (``SplitTouchingLeaves`` at ``leaf_split_angle_deg``; 0 =
    not), and so are blades joined by a neck in their outline
    (``SplitLeafNecks``) and blades lying flush (``SplitOversizedLeaves``). ``focus_W`` (W, m): only the instances whose points' centroid lies
    within ``focus_radius`` of it are completed (the re-estimate of the fruit
    being revealed; every fruit's points still count as outside the others).
    The fruits are completed in ``workers`` threads (default: one per CPU;
    each fit is independent and seeded, so the result does not depend on
    it); ``timings`` sums the fruits' seconds (``fits_reused``: the fits
    taken from ``memo``, a ``FitMemo`` kept across the views of an episode)."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    P = params or SscConfig()
    timings = {} if timings is None else timings
    cam = np.asarray(semantic.X_WC, float)[:3, 3]
    out = PlantEstimate(semantic=semantic, branch=_Branches(semantic, cam, branch_params,
                                                            timings))
    if leaf_split_angle_deg > 0 and len(semantic.leaf_points_W):
        ids = SplitTouchingLeaves(semantic.leaf_points_W, semantic.leaf_instance, cam,
                                  leaf_split_angle_deg)
        ids = SplitLeafNecks(semantic.leaf_points_W, ids)
        ids = SplitOversizedLeaves(semantic.leaf_points_W, ids)
        semantic = out.semantic = dc.replace(semantic, leaf_instance=ids)
    if "no_fruit_in_view" in semantic.flags:
        return out
    pts, inst = np.asarray(semantic.fruit_points_W, float), np.asarray(semantic.fruit_instance)
    groups = [[i] for i in FruitInstances(semantic, min_fruit_points)]
    if focus_W is not None:
        focus = np.asarray(focus_W, float).reshape(3)
        groups = [g for g in groups
                  if np.linalg.norm(pts[np.isin(inst, g)].mean(axis=0) - focus) <= focus_radius]

    if memo is not None:
        memo.NewView()
    key = (method, repr(P), float(free_space_voxel), np.round(np.asarray(semantic.X_WC, float),
                                                           6).tobytes())

    def complete(g, into: dict, keep=None):
        """The fit of instances ``g``; kept in ``memo`` unless ``keep(fit)``
        is False (a union that does not hold its fragments)."""
        mine = np.isin(inst, g)
        hood = None
        if memo is not None:
            est, hood = memo.Find(key, semantic, pts[mine])
            if est is not None:
                into["fits_reused"] = into.get("fits_reused", 0) + 1
                return est
        est = _CompleteFruit(semantic, pts[mine], pts[~mine], out.branch, decoder,
                             mean_latent, P, method, free_space_voxel, into)
        if memo is not None and (keep is None or keep(est)):
            memo.Add(key, pts[mine], hood, est)
        return est

    def complete_apart(g):          # a thread's own timings, summed below
        t = {}
        return complete(g, t), t
    done = ParallelMap(complete_apart, groups, workers)
    ests = [e for e, _ in done]
    for _, t in done:
        for k, v in t.items():
            timings[k] = timings.get(k, 0.0) + v
    # A leaf across a fruit splits its visible part into fragments that
    # cluster apart: fragments lying on one another's completed surface are
    # one fruit, completed again from all of them.
    # If the union's fit cannot hold both (``UnionExplains``), the two cannot
    # be one fruit, nor two (their fits overlap or lie on each other): the
    # smaller one's points are not kept as fruit, if it is the much smaller
    # one (``DROP_FRACTION``). A much smaller one whose fit only
    # interpenetrates the other's (``OVERLAP_FRACTION``) is not kept either.
    merged = True
    dropped: list[int] = []
    while merged and len(groups) > 1:
        merged = False
        for a in range(len(groups)):
            for b in range(a + 1, len(groups)):
                pa, pb = pts[np.isin(inst, groups[a])], pts[np.isin(inst, groups[b])]
                small = b if len(pb) <= len(pa) else a
                lopsided = min(len(pa), len(pb)) <= DROP_FRACTION * max(len(pa), len(pb))
                near = (FruitsOverlap(ests[a], ests[b], MERGE_OVERLAP_FRACTION)
                        or PointsOnFruit(ests[a], pb, merge_distance)
                        or PointsOnFruit(ests[b], pa, merge_distance))
                if near:
                    parts = [(p, MedianAbsSdf(e, p)) for p, e in ((pa, ests[a]), (pb, ests[b]))]
                    holds = lambda u: UnionExplains(u, parts, merge_tolerance)  # noqa: E731
                    union = complete(groups[a] + groups[b], timings, keep=holds)
                    if holds(union) or not lopsided:
                        groups[a] = groups[a] + groups.pop(b)
                        ests.pop(b)
                        ests[a] = union
                        merged = True
                        break
                if lopsided and (near or FruitsOverlap(ests[a], ests[b], OVERLAP_FRACTION)):
                    dropped += groups.pop(small)
                    ests.pop(small)
                    merged = True
                    break
            if merged:
                break
    out.fruits = ests
    out.fruit_ids = [g[0] for g in groups]
    if any(len(g) > 1 for g in groups) or dropped:
        # the merged fragments carry the id of their largest part; the
        # dropped ones are no fruit's (-1)
        conf = MergedConfidence(getattr(semantic, "fruit_confidence", {}), inst, groups)
        inst = inst.copy()
        for g in groups:
            inst[np.isin(inst, g)] = g[0]
        inst[np.isin(inst, dropped)] = -1
        flags = list(semantic.flags) + ([f"{DROPPED_FLAG}:{len(dropped)}"]
                                        if dropped else [])
        out.semantic = dc.replace(semantic, fruit_instance=inst, flags=flags,
                                  fruit_confidence=conf)
    return out


def MergedConfidence(confidence: dict, inst: np.ndarray, groups: list[list[int]]) -> dict:
    """The fruit confidences (``SemanticScene.fruit_confidence``) after the
    fragments of each group are merged under its first id: their mean
    weighted by their points (the fragments without one left out)."""
    out = dict(confidence)
    for g in groups:
        have = [(confidence[i], np.count_nonzero(inst == i)) for i in g if i in confidence]
        if len(g) > 1 and have and sum(n for _, n in have):
            out[g[0]] = round(sum(c * n for c, n in have) / sum(n for _, n in have), 4)
    return out


def DroppedFragments(flags) -> int:
    """How many fruit fragments ``CompletePlant`` dropped in a view, from
    its scene's ``flags`` (``fruit_fragment_dropped:N``); 0 when none."""
    return sum(int(f.split(":", 1)[1]) for f in flags or ()
               if f.startswith(DROPPED_FLAG + ":"))


def UnionExplains(union, parts, tolerance: float = MERGE_RESIDUAL_TOLERANCE) -> bool:
    """The union's fit puts every part's points (``parts``: (points, the
    median |SDF| the part's own fit gave them, NaN = unknown)) within
    ``tolerance`` (m) of that median."""
    if union is None or union.sdf_W is None:
        return False
    return all(not len(points) or np.isnan(mine) or
               MedianAbsSdf(union, points) <= mine + tolerance for points, mine in parts)


def MedianAbsSdf(est, points: np.ndarray) -> float:
    """Median |SDF| (m) of ``points`` to ``est``'s completed surface; NaN
    without an estimate, an SDF or points."""
    if est is None or est.sdf_W is None or len(points) == 0:
        return float("nan")
    return float(np.median(np.abs(np.asarray(est.sdf_W(points), float))))


def FruitsOverlap(a, b, fraction: float = OVERLAP_FRACTION) -> bool:
    """Two estimates whose centres are closer than ``fraction`` of the sum of
    their mean radii: at 1 (the default) they interpenetrate, which two real
    fruits cannot; fragments of one fruit complete to shapes overlapping
    more (``MERGE_OVERLAP_FRACTION``)."""
    if a is None or b is None:
        return False
    r = [float(np.mean(np.linalg.norm(e.vertices_W - e.center_W, axis=1))) for e in (a, b)]
    return float(np.linalg.norm(a.center_W - b.center_W)) < fraction * (r[0] + r[1])


def PointsOnFruit(est, points: np.ndarray, distance: float) -> bool:
    """``points`` (another fragment's) lie on ``est``'s completed surface:
    their median |SDF| is below ``distance`` (m)."""
    return MedianAbsSdf(est, points) < distance     # False for NaN
