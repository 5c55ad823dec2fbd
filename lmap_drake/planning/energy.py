"""The petiole's load from an action: the turn of the grasp about the
estimated attachment (hinge), bending and torsion as one equivalent turn,
its bending energy per leaf node, two motions' compounded energy, and the
lever-scaled caps on straight pulls and arcs. (The tether elongation is
``hazard.TetherElongation``.) World frame W, metres, degrees where named."""
from __future__ import annotations

import numpy as np

from lmap_drake.planning.config import PlannerConfig


def HingeRotationDeg(hinge_W, p_from_W, p_to_W) -> float:
    """Angle (deg) by which the grasp point turned about the hinge, from
    ``p_from_W`` to ``p_to_W``; NaN without a hinge."""
    if hinge_W is None:
        return float("nan")
    u, v = np.asarray(p_from_W) - hinge_W, np.asarray(p_to_W) - hinge_W
    c = u @ v / max(np.linalg.norm(u) * np.linalg.norm(v), 1e-12)
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def EquivalentTurnDeg(bend_deg: float, twist_rad: float, torsion_ratio: float) -> float:
    """The petiole's load as one turn (deg): sqrt(bend^2 + ratio twist^2),
    ``bend_deg`` the turn of the grasp point about the hinge, ``twist_rad``
    the leaf's twist about the hinge-grasp line and ``ratio`` the petiole's
    torsional to bending stiffness (the energies k_b bend^2 + k_t twist^2
    written as one bend). NaN without a hinge."""
    if not np.isfinite(bend_deg):
        return bend_deg
    return float(np.hypot(bend_deg, np.sqrt(max(torsion_ratio, 0.0)) * np.degrees(twist_rad)))


def PetioleBendingEnergy(hinge_deg: float, weight: float) -> float:
    """Per leaf node (m^2): ``weight`` * theta^2 (theta in rad), the petiole
    bending where it joins the branch when the leaf turns by theta about
    it. The deformation graph ties the leaf to the branch by a chain of
    nodes whose bending ARAP barely resists, so without this term a
    60-degree swing of the leaf costs ~50x less than an 8 cm pull, while
    the FEM petiole carries 40-60 % of that pull's force (measured with
    ``scripts/eval_hazard_prediction.py``). 0 without a hinge."""
    if not np.isfinite(hinge_deg):
        return 0.0
    return float(weight * np.radians(hinge_deg) ** 2)


def CompoundEnergyPerNode(before: float, after: float) -> float:
    """An upper bound of the ARAP energy per node of two motions executed in
    turn, ``before`` (from the rest shape) and ``after`` (predicted from the
    shape ``before`` left): sqrt(E) is a norm of the deformation for small
    strains, so sqrt(E_total) <= sqrt(E_before) + sqrt(E_after). Their sum
    assumes the two deformations independent; a motion that keeps loading
    the leaf the same way compounds (a pull, then an arc or a twist: 14.6
    and 15.4 N on the petiole in two multi-fruit episodes whose summed
    energies per node, 4.4 and 3.6e-7, were under the cap)."""
    before, after = max(0.0, float(before)), max(0.0, float(after))
    return float((np.sqrt(before) + np.sqrt(after)) ** 2)


# The grasp-attachment lever (m) at which ``planner.max_pull_distance`` holds.
PULL_LEVER_REFERENCE = 0.10


# m: the longest straight pull the cap was measured on (380 pulls of 1.5-4.5
# cm, ``PlannerConfig.max_pull_distance``); the (L / 10 cm)^2 scaling is not
# extrapolated past it. Two 6 cm pulls it allowed at a 14 cm lever loaded
# their petioles 19.4 and 21.1 N (random_multi_9393_002 and _004, external
# peppers; docs/explanation/multi-fruit.md).
MEASURED_PULL_MAX = 0.045


def LeverPullDistance(cfg: PlannerConfig, p_WG: np.ndarray,
                      hinge_W: np.ndarray | None) -> float:
    """``planner.max_pull_distance`` times (L / ``PULL_LEVER_REFERENCE``)^2
    (m), L the grasp ``p_WG``'s distance to the estimated attachment
    ``hinge_W`` (the leaf as a beam clamped at its petiole: a grasp moved by
    d bends the petiole with a moment that grows as d / L^2). Without a
    hinge the cap is not scaled; inf when ``max_pull_distance`` is 0."""
    cap = cfg.max_pull_distance
    if cap <= 0:
        return float("inf")
    if hinge_W is not None:
        lever = float(np.linalg.norm(np.asarray(p_WG, float) - np.asarray(hinge_W, float)))
        cap *= (lever / PULL_LEVER_REFERENCE) ** 2
    return cap


def MaxPullDistance(cfg: PlannerConfig, p_WG: np.ndarray,
                    hinge_W: np.ndarray | None) -> float:
    """The longest straight pull (m) allowed from grasp ``p_WG``: the
    lever's (``LeverPullDistance``), at most ``MEASURED_PULL_MAX``; inf
    when ``max_pull_distance`` is 0 (no cap)."""
    cap = LeverPullDistance(cfg, p_WG, hinge_W)
    return cap if not np.isfinite(cap) else min(cap, MEASURED_PULL_MAX)


# The widest arc (deg) allowed at ``planner.arc_lever_reference``.
ARC_REFERENCE_DEG = 45.0


def MaxArcAngle(cfg: PlannerConfig, p_WG: np.ndarray, hinge_W: np.ndarray | None) -> float:
    """The widest arc (deg) about the estimated attachment ``hinge_W``
    allowed from grasp ``p_WG``: ``ARC_REFERENCE_DEG`` times L /
    ``planner.arc_lever_reference``, L the grasp's distance to it, at most
    ``ARC_REFERENCE_DEG``. Turning the blade by a given angle takes a
    moment at the petiole, and the grasp supplies it with a force that grows
    as the lever shortens. inf when ``arc_lever_reference`` is 0 or there
    is no hinge (no cap)."""
    ref = cfg.arc_lever_reference
    if ref <= 0 or hinge_W is None:
        return float("inf")
    lever = float(np.linalg.norm(np.asarray(p_WG, float) - np.asarray(hinge_W, float)))
    return ARC_REFERENCE_DEG * min(1.0, lever / ref)
