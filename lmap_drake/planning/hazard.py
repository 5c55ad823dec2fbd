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
