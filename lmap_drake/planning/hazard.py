"""Predicted petiole loading of a leaf action (a second hazard measure next
to the ARAP energy, which ranks leaf strain). World frame W, metres.

The petiole is stiff along its axis and soft in bending, so what loads it is
the leaf being pulled *away* from where it joins the branch, whatever the
blade does. Two measures from the predicted deformation:

- ``tether_elongation_m``: how much farther the grasp point ends from the
  hinge (the estimated petiole attachment) than it started, |p_end - a| -
  |p_WG - a| (m). Zero for an arc about the hinge, d cos(angle) for a pull.
- ``petiole_stretch``: the largest relative increase of the distance to
  the hinge over the predicted leaf nodes within ``radius`` of it (the
  petiole and the leaf base), (|x'_i - a| - |x_i - a|) / |x_i - a|.

And the misfit of a rotation about a wrong hinge: the gripper holds the
blade rigidly, so where the true attachment sits in the gripper's frame is
fixed by the leaf; a motion that moves it there (``AttachmentMisfit``) must
be taken up by the petiole and blade. An arc or twist about the estimate
``h`` moves the true attachment ``h + e`` by |(R - I) e| <= 2 sin(theta/2)
|e| in the gripper's frame, over the held material's length L (the lever):
``HingeMisfitStrain``.
"""
from __future__ import annotations

import numpy as np

from lmap_drake.deformation.graph import FREE


def TetherElongation(p_from_W: np.ndarray, p_to_W: np.ndarray, hinge_W: np.ndarray) -> float:
    """How much farther from the hinge (m) a grasp moved from ``p_from_W``
    to ``p_to_W`` ends: |p_to - a| - |p_from - a|."""
    h = np.asarray(hinge_W, float)
    return float(np.linalg.norm(np.asarray(p_to_W, float) - h)
                 - np.linalg.norm(np.asarray(p_from_W, float) - h))


def HazardMeasures(actions: list, predictions: list, hinge_W: np.ndarray | None,
                   radius: float = 0.03) -> list[dict]:
    """Per action (aligned with ``predictions``, ``PredictedDeformation``):
    {'tether_elongation_m', 'petiole_stretch'}; NaN without a hinge."""
    out = []
    for a, p in zip(actions, predictions):
        if hinge_W is None:
            out.append({"tether_elongation_m": float("nan"), "petiole_stretch": float("nan")})
            continue
        h = np.asarray(hinge_W, float)
        tether = TetherElongation(a.p_WG, a.p_WG + a.dp_W, h)
        free = np.asarray(p.node_kind) == FREE
        x0 = np.asarray(p.nodes_W)[free]
        x1 = np.asarray(p.deformed_nodes_W)[free]
        r0 = np.linalg.norm(x0 - h, axis=1)
        near = (r0 < radius) & (r0 > 1e-3)
        stretch = (float(np.max((np.linalg.norm(x1[near] - h, axis=1) - r0[near]) / r0[near]))
                   if near.any() else 0.0)
        out.append({"tether_elongation_m": tether, "petiole_stretch": max(0.0, stretch)})
    return out


def AttachmentMisfit(action, attach_W: np.ndarray) -> float:
    """How far (m) ``action`` (an ``Action``) moves the point ``attach_W``
    (W) in the gripper's frame: |R_delta^T (a - p_end) - (a - p_WG)|, the
    displacement the held leaf must take up between the pads and its
    attachment at ``attach_W`` (0 for an arc or twist about that very
    point; a pull's length for a pull)."""
    a = np.asarray(attach_W, float)
    p0 = np.asarray(action.p_WG, float)
    p1 = p0 + np.asarray(action.dp_W, float)
    return float(np.linalg.norm(np.asarray(action.R_delta).T @ (a - p1) - (a - p0)))


def HingeMisfitStrain(angle_rad: float, lever_m: float, hinge_error_m: float) -> float:
    """The largest misfit (``AttachmentMisfit``) a rotation by ``angle_rad``
    about a line through the estimated attachment can give when the true
    attachment is ``hinge_error_m`` from the estimate, 2 sin(theta/2) e,
    over the held material's length ``lever_m`` (the grasp's distance to
    the estimate): a strain-like ratio (inf for a zero lever)."""
    if lever_m <= 0:
        return float("inf")
    return float(2.0 * abs(np.sin(angle_rad / 2.0)) * hinge_error_m / lever_m)


def TurnAngle(R_from: np.ndarray, R_to: np.ndarray) -> float:
    """The angle (rad, [0, pi]) of the rotation R_to R_from^T."""
    R = np.asarray(R_to, float) @ np.asarray(R_from, float).T
    return float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


def MisfitReason(action, hinge_W: np.ndarray | None, R_WG0: np.ndarray | None,
                 hinge_error: float, max_misfit: float) -> str:
    """'' or why ``action`` (an arc or twist; pulls pass) may stretch the
    held blade: its gripper's total turn from the first grasp orientation
    ``R_WG0`` (None: this action's own grasp), about a hinge estimate
    ``hinge_error`` (m) off, gives a ``HingeMisfitStrain`` above
    ``max_misfit`` at the grasp's lever to ``hinge_W``. No hinge, or
    ``max_misfit`` 0: ''."""
    if action.family == "pull" or hinge_W is None or max_misfit <= 0:
        return ""
    R0 = action.R_WG if R_WG0 is None else R_WG0
    turn = TurnAngle(R0, action.R_WG_end)
    lever = float(np.linalg.norm(np.asarray(action.p_WG, float) - np.asarray(hinge_W, float)))
    misfit = HingeMisfitStrain(turn, lever, hinge_error)
    if misfit <= max_misfit + 1e-9:
        return ""
    return (f"a {np.degrees(turn):.0f} deg turn from a grasp {lever * 100:.1f} cm from the "
            f"attachment may stretch the held blade (hinge misfit {misfit:.2f} > "
            f"max_hinge_misfit {max_misfit:g} at hinge_error {hinge_error * 100:g} cm)")
