"""Leaf manipulation actions a = (p_WG, R_WG, dp_W) (paper Sec. III-B) and
the candidate pull directions / distances (Sec. III-C-1). World frame W, m.

Gripper frame G (Robotiq 2F-85 ``tcp``): z is the approach axis, y the
finger closing direction, x the pads' in-plane width direction. The pads
face each other along y, so the pads' plane (where the pinched leaf lies)
is the G x-z plane.
"""
from __future__ import annotations

import dataclasses as dc
import itertools

import numpy as np


class DeformationError(ValueError):
    """The deformation model cannot be built or solved for this input
    (empty leaf, no branch to fix the leaf to, grasp off the leaf, ...)."""


@dc.dataclass
class Action:
    """Grasp the leaf at ``p_WG`` (3, m) with gripper orientation ``R_WG``
    (3x3) and move the gripper by ``dp_W`` (3, m) without rotating it.
    ``grasp_id`` / ``direction_id`` are bookkeeping indices (-1 = unset)."""
    p_WG: np.ndarray
    R_WG: np.ndarray
    dp_W: np.ndarray
    grasp_id: int = -1
    direction_id: int = -1

    def __post_init__(self):
        self.p_WG = np.asarray(self.p_WG, dtype=float).reshape(3)
        self.R_WG = np.asarray(self.R_WG, dtype=float).reshape(3, 3)
        self.dp_W = np.asarray(self.dp_W, dtype=float).reshape(3)

    def __eq__(self, other) -> bool:
        return (isinstance(other, Action) and np.array_equal(self.p_WG, other.p_WG)
                and np.array_equal(self.R_WG, other.R_WG) and np.array_equal(self.dp_W, other.dp_W)
                and (self.grasp_id, self.direction_id) == (other.grasp_id, other.direction_id))

    @property
    def distance(self) -> float:
        """Move distance |dp_W| (m)."""
        return float(np.linalg.norm(self.dp_W))

    @property
    def direction_W(self) -> np.ndarray:
        """Unit pull direction in W (zero vector for a zero move)."""
        d = self.distance
        return self.dp_W / d if d > 0 else np.zeros(3)

    def grasp_key(self) -> bytes:
        """Actions with equal keys share a grasp pose (and an ARAP factorisation)."""
        return np.concatenate([self.p_WG, self.R_WG.ravel()]).tobytes()


def PullDirections() -> np.ndarray:
    """The paper's 14 pull directions (14, 3), unit vectors in W: the 6 axial
    (+-x, +-y, +-z) then the 8 diagonal (+-1, +-1, +-1)/sqrt(3)."""
    axial = np.vstack([np.eye(3), -np.eye(3)])
    diag = np.array(list(itertools.product([1.0, -1.0], repeat=3))) / np.sqrt(3.0)
    return np.vstack([axial, diag])


def MakeActions(grasps: list[tuple[np.ndarray, np.ndarray]],
                directions: np.ndarray, distances: list[float]) -> list[Action]:
    """All (grasp, direction, distance) combinations, grasp-major.
    ``grasps``: (p_WG, R_WG) pairs; ``directions``: (D, 3) unit vectors in W;
    ``distances``: move distances (m)."""
    directions = np.asarray(directions, dtype=float).reshape(-1, 3)
    out = []
    for g, (p_WG, R_WG) in enumerate(grasps):
        for d, u in enumerate(directions):
            for s in distances:
                out.append(Action(p_WG, R_WG, float(s) * u, grasp_id=g, direction_id=d))
    return out


def GroupActionsByGrasp(actions: list[Action]) -> list[list[int]]:
    """Indices of ``actions`` grouped by grasp pose, in first-seen order."""
    groups: dict[bytes, list[int]] = {}
    for i, a in enumerate(actions):
        groups.setdefault(a.grasp_key(), []).append(i)
    return list(groups.values())
