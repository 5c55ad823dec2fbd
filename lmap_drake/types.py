"""Data passed between pipeline stages (world frame W, metres). Small
dataclasses of numpy arrays; heavy objects (decoders, KD-trees) stay
attributes of the systems that own them."""
from __future__ import annotations

import dataclasses as dc
import hashlib
from typing import Callable

import numpy as np


def _empty3() -> np.ndarray:
    return np.zeros((0, 3))


def _empty_ids() -> np.ndarray:
    return np.zeros(0, dtype=np.int64)


@dc.dataclass
class SemanticScene:
    """Segmented points in the world frame (m) with per-point instance ids
    (-1 = unassigned), plus the camera pose ``X_WC`` (4x4) they came from.
    ``flags`` carries conditions such as ``"no_fruit_in_view"``."""
    branch_points_W: np.ndarray = dc.field(default_factory=_empty3)
    leaf_points_W: np.ndarray = dc.field(default_factory=_empty3)
    fruit_points_W: np.ndarray = dc.field(default_factory=_empty3)
    branch_instance: np.ndarray = dc.field(default_factory=_empty_ids)
    leaf_instance: np.ndarray = dc.field(default_factory=_empty_ids)
    fruit_instance: np.ndarray = dc.field(default_factory=_empty_ids)
    X_WC: np.ndarray = dc.field(default_factory=lambda: np.eye(4))
    flags: list[str] = dc.field(default_factory=list)
    # Added by perception: how many camera views were fused into these sets.
    num_views: int = 1
    # Ends of camera rays (from X_WC) that met no plant part: background
    # surfaces (robot included), or a point at the no-return range for
    # pixels beyond the sensor's range. Only used to carve free space.
    background_points_W: np.ndarray = dc.field(default_factory=_empty3)
    # {fruit instance id: the segmenter's confidence that it is a fruit, in
    # [0, 1]} (``perception.points.BuildSemanticScene``: the mean over the
    # instance's pixels of their segmentation instance's confidence); an id
    # not in it has none (the planner then takes it as a fruit).
    fruit_confidence: dict = dc.field(default_factory=dict)

    def is_empty(self) -> bool:
        return (len(self.branch_points_W) + len(self.leaf_points_W)
                + len(self.fruit_points_W)) == 0

    def Fingerprint(self) -> str:
        """A digest of every field: equal for scenes with equal contents
        (a view segmented again gives a new object with the same digest)."""
        h = hashlib.blake2b(digest_size=16)
        for f in dc.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, np.ndarray):
                a = np.ascontiguousarray(v)
                h.update(f"{f.name}{a.dtype}{a.shape}".encode())
                h.update(a.tobytes())
            else:
                h.update(f"{f.name}={v!r}".encode())
        return h.hexdigest()


@dc.dataclass
class BranchEstimate:
    """Completed branch: triangle mesh and surface samples (W, m), unit axis."""
    vertices_W: np.ndarray
    faces: np.ndarray
    samples_W: np.ndarray
    axis_W: np.ndarray


@dc.dataclass
class ShapeHypotheses:
    """The fruit shapes a view leaves plausible (``shape.hypotheses``): the
    kept hypotheses' meshes (W, m), Sim(3) ``X_WO`` (K,4,4), latents (K,C),
    volumes (cm^3), volume centroids (W, m), axes (W, unit), RMS surface
    residuals (m), the fraction of the fruit points near each surface and
    the fraction of negative points deeper than 2 mm in each;
    ``num_fitted`` hypotheses were fitted. Intervals over the kept ones: ``volume_interval_cm3`` (lo, hi; the 90 % interval),
    ``center_interval_W`` (2,3: lowest and highest per world axis, m),
    ``axis_spread_deg`` (largest angle to the estimate's axis)."""
    vertices_W: list
    faces: list
    X_WO: np.ndarray
    latents: np.ndarray
    volume_cm3: np.ndarray
    center_W: np.ndarray
    axis_W: np.ndarray
    residual_m: np.ndarray
    inlier_fraction: np.ndarray
    inside_fraction: np.ndarray
    num_fitted: int
    volume_interval_cm3: np.ndarray
    center_interval_W: np.ndarray
    axis_spread_deg: float
    seconds: float = 0.0

    def Record(self) -> dict:
        """A compact JSON form (no meshes: each hypothesis is its latent
        and X_WO, from which ``shape.ssc.MakeFruitEstimate`` rebuilds it)."""
        def r(a, n=5):
            return np.round(np.asarray(a, float), n).tolist()
        return {"num_fitted": self.num_fitted, "num_kept": len(self.volume_cm3),
                "volume_interval_cm3": r(self.volume_interval_cm3, 2),
                "center_interval_W": r(self.center_interval_W),
                "axis_spread_deg": round(float(self.axis_spread_deg), 2),
                "volume_cm3": r(self.volume_cm3, 2), "center_W": r(self.center_W),
                "axis_W": r(self.axis_W, 4), "residual_m": r(self.residual_m, 6),
                "X_WO": r(self.X_WO, 6), "latents": r(self.latents, 5)}
        # (its fit time is in the stage timings, ``hypotheses_s``: a record
        # holds what two runs of one episode agree on)


@dc.dataclass
class FruitEstimate:
    """Completed fruit. ``X_WO`` is the Sim(3) object-to-world map as a 4x4
    (scale folded into the rotation block); ``sdf_W`` maps (N,3) world
    points to signed distances in metres (negative inside)."""
    vertices_W: np.ndarray
    faces: np.ndarray
    X_WO: np.ndarray
    latent: np.ndarray
    center_W: np.ndarray
    peduncle_axis_W: np.ndarray
    sdf_W: Callable[[np.ndarray], np.ndarray] | None = None
    loss_trace: list[dict] = dc.field(default_factory=list)
    # the plausible shapes besides this one (None: not fitted)
    hypotheses: ShapeHypotheses | None = None


@dc.dataclass
class SceneEstimate:
    """What shape completion hands to the planner. ``leaf_attachment_W``
    (K, 3): points that tie the observed leaf to the branch where its
    petiole was not seen (a virtual petiole; see
    ``lmap_drake.planning.attachment.AttachLeaf``), part of the leaf for the
    deformation model."""
    semantic: SemanticScene
    branch: BranchEstimate | None = None
    fruit: FruitEstimate | None = None
    leaf_attachment_W: np.ndarray = dc.field(default_factory=_empty3)
    # Plants with several fruits and leaves: the other fruits (obstacles for
    # the robot and the leaf, occluders of the target ``fruit``) and the
    # other leaves' observed points (occluders and obstacles), W, metres.
    other_fruits: list = dc.field(default_factory=list)
    other_leaves_W: np.ndarray = dc.field(default_factory=_empty3)


@dc.dataclass
class PlantEstimate:
    """Every fruit of a plant completed (paper Sec. III-F): ``fruits[k]`` is
    the estimate of the fruit instance ``fruit_ids[k]`` of ``semantic``;
    ``branch`` the completed branches (all instances)."""
    semantic: SemanticScene
    branch: BranchEstimate | None = None
    fruits: list = dc.field(default_factory=list)
    fruit_ids: list = dc.field(default_factory=list)
