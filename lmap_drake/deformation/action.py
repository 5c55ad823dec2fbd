"""Leaf manipulation actions (paper Sec. III-B) and the candidate pull
directions / distances (Sec. III-C-1). World frame W, m, rad.

Two families of motion from the grasp pose (p_WG, R_WG):
- ``pull`` (the paper's a = (p_WG, R_WG, dp_W)): the gripper moves by dp_W
  in a straight line without rotating;
- ``arc`` (hinge-aware, ours): the gripper rotates rigidly by ``angle``
  about the line through ``pivot_W`` (the leaf's estimated petiole
  attachment) along ``axis_W``, as the leaf would swing about its petiole:
  p(f) = pivot + R(f angle) (p_WG - pivot), R_WG(f) = R(f angle) R_WG.
  A straight pull stretches the petiole; an arc about the attachment keeps
  the attachment-grasp distance.
- ``twist`` (ours): the same rigid rotation about the attachment-grasp line
  itself (``axis_W`` along p_WG - pivot_W): the grasp point stays, the
  gripper turns about it and the blade turns about the line toward
  edge-on; the petiole is twisted, not bent or stretched.
Both end at a gripper pose X_end = (p_WG + dp_W, R_delta R_WG); the
deformation graph's handle moves rigidly with the gripper.

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


FAMILIES = ("pull", "arc", "twist")
ROTATIONS = ("arc", "twist")     # families that rotate the gripper about a line
# Arc actions number their (axis) directions from here, after the pulls';
# twists from TWIST_DIRECTION_BASE (+0: positive sense about the
# attachment -> grasp line, +1: negative).
ARC_DIRECTION_BASE = 100
TWIST_DIRECTION_BASE = 200


def AxisAngleMatrix(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation (3x3) by ``angle`` (rad) about the unit ``axis`` (Rodrigues)."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


@dc.dataclass
class Action:
    """Grasp the leaf at ``p_WG`` (3, m) with gripper orientation ``R_WG``
    (3x3), then move the gripper: ``family`` 'pull' moves it by ``dp_W``
    (3, m) without rotating it; 'arc' and 'twist' rotate it by ``angle``
    (rad) about the axis ``axis_W`` (unit, 3) through ``pivot_W`` (3, m),
    and ``dp_W`` is then derived (the TCP's net displacement). ``grasp_id`` /
    ``direction_id`` are bookkeeping indices (-1 = unset)."""
    p_WG: np.ndarray
    R_WG: np.ndarray
    dp_W: np.ndarray | None = None
    grasp_id: int = -1
    direction_id: int = -1
    family: str = "pull"
    pivot_W: np.ndarray | None = None
    axis_W: np.ndarray | None = None
    angle: float = 0.0

    def __post_init__(self):
        self.p_WG = np.asarray(self.p_WG, dtype=float).reshape(3)
        self.R_WG = np.asarray(self.R_WG, dtype=float).reshape(3, 3)
        if self.family not in FAMILIES:
            raise ValueError(f"unknown action family {self.family!r} (one of {FAMILIES})")
        if self.family in ROTATIONS:
            if self.pivot_W is None or self.axis_W is None:
                raise ValueError(f"a {self.family} action needs pivot_W and axis_W")
            self.pivot_W = np.asarray(self.pivot_W, float).reshape(3)
            self.axis_W = np.asarray(self.axis_W, float).reshape(3)
            self.axis_W = self.axis_W / np.linalg.norm(self.axis_W)
            self.angle = float(self.angle)
            R = AxisAngleMatrix(self.axis_W, self.angle)
            self.dp_W = self.pivot_W + R @ (self.p_WG - self.pivot_W) - self.p_WG
        else:
            if self.dp_W is None:
                raise ValueError("a pull action needs dp_W")
            self.dp_W = np.asarray(self.dp_W, dtype=float).reshape(3)

    def __eq__(self, other) -> bool:
        def same(a, b):
            return (a is None and b is None) or (
                a is not None and b is not None and np.array_equal(a, b))
        return (isinstance(other, Action) and np.array_equal(self.p_WG, other.p_WG)
                and np.array_equal(self.R_WG, other.R_WG) and np.array_equal(self.dp_W, other.dp_W)
                and (self.grasp_id, self.direction_id) == (other.grasp_id, other.direction_id)
                and self.family == other.family and same(self.pivot_W, other.pivot_W)
                and same(self.axis_W, other.axis_W) and self.angle == other.angle)

    @property
    def R_delta(self) -> np.ndarray:
        """Rotation of the gripper over the motion, in W (I for a pull)."""
        if self.family in ROTATIONS:
            return AxisAngleMatrix(self.axis_W, self.angle)
        return np.eye(3)

    @property
    def R_WG_end(self) -> np.ndarray:
        """Gripper orientation at the end of the motion."""
        return self.R_delta @ self.R_WG

    def Poses(self, step: float = 0.01, max_angle: float = np.deg2rad(5.0)
              ) -> list[tuple[np.ndarray, np.ndarray]]:
        """TCP poses (p_WG, R_WG) along the motion, the start excluded and
        the end included, about ``step`` m and at most ``max_angle`` rad apart."""
        n = max(2, int(np.ceil(self.path_length / step)),
                int(np.ceil(abs(self.angle) / max_angle)))
        out = []
        for k in range(1, n + 1):
            f = k / n
            if self.family in ROTATIONS:
                R = AxisAngleMatrix(self.axis_W, f * self.angle)
                out.append((self.pivot_W + R @ (self.p_WG - self.pivot_W), R @ self.R_WG))
            else:
                out.append((self.p_WG + self.dp_W * k / n, self.R_WG))
        return out

    @property
    def path_length(self) -> float:
        """Length (m) of the TCP's path (the arc's length for an arc; about
        0 for a twist, which turns the gripper in place)."""
        if self.family in ROTATIONS:
            return float(abs(self.angle) * np.linalg.norm(
                np.cross(self.axis_W, self.p_WG - self.pivot_W)))
        return self.distance

    def Describe(self) -> str:
        """Short human-readable form, e.g. 'pull 4 cm', 'arc 30 deg (6.1 cm)'
        or 'twist -60 deg'."""
        if self.family == "twist":
            return f"twist {np.rad2deg(self.angle):.0f} deg"
        if self.family == "arc":
            return f"arc {np.rad2deg(self.angle):.0f} deg ({self.distance * 100:.1f} cm)"
        return f"pull {self.distance * 100:.0f} cm"

    @property
    def distance(self) -> float:
        """Net TCP displacement |dp_W| (m) (an arc's chord)."""
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


def HingeAxes(p_WG: np.ndarray, pivot_W: np.ndarray, num_axes: int = 8) -> np.ndarray:
    """``num_axes`` unit rotation axes (k, 3) perpendicular to the line from
    the hinge ``pivot_W`` to the grasp ``p_WG``, evenly spread over the
    circle (so the arcs sweep the grasp point in evenly spread planes,
    both senses included): axis 0 is horizontal (the arc lifts or lowers
    the grasp), axis num_axes/4 swings it sideways."""
    r = np.asarray(p_WG, float) - np.asarray(pivot_W, float)
    r_hat = r / max(np.linalg.norm(r), 1e-12)
    e1 = np.cross(r_hat, [0.0, 0.0, 1.0])
    if np.linalg.norm(e1) < 1e-6:             # the leaf hangs vertically
        e1 = np.cross(r_hat, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(r_hat, e1)
    phi = 2 * np.pi * np.arange(num_axes) / num_axes
    return np.outer(np.cos(phi), e1) + np.outer(np.sin(phi), e2)


def MakeArcActions(p_WG: np.ndarray, R_WG: np.ndarray, pivot_W: np.ndarray,
                   axes: np.ndarray, angles: list[float], grasp_id: int = -1,
                   axis_ids=None) -> list[Action]:
    """Arc actions of one grasp about ``pivot_W``: every axis (rows of
    ``axes``) at every angle (rad); direction ids ``ARC_DIRECTION_BASE +
    axis index`` unless ``axis_ids`` are given."""
    axes = np.asarray(axes, float).reshape(-1, 3)
    ids = range(len(axes)) if axis_ids is None else axis_ids
    return [Action(p_WG, R_WG, grasp_id=grasp_id, direction_id=ARC_DIRECTION_BASE + int(j),
                   family="arc", pivot_W=pivot_W, axis_W=k, angle=float(a))
            for k, j in zip(axes, ids) for a in angles]


def MakeTwistActions(p_WG: np.ndarray, R_WG: np.ndarray, pivot_W: np.ndarray,
                     angles: list[float], grasp_id: int = -1) -> list[Action]:
    """Twist actions of one grasp: the gripper turns by +-each angle (rad)
    about the line from the hinge ``pivot_W`` through the grasp ``p_WG``
    (direction ids ``TWIST_DIRECTION_BASE`` + 0 / + 1 for the two senses)."""
    axis = np.asarray(p_WG, float) - np.asarray(pivot_W, float)
    axis = axis / np.linalg.norm(axis)
    return [Action(p_WG, R_WG, grasp_id=grasp_id, direction_id=TWIST_DIRECTION_BASE + j,
                   family="twist", pivot_W=pivot_W, axis_W=sense * axis, angle=float(a))
            for j, sense in enumerate((1.0, -1.0)) for a in angles]


def GroupActionsByGrasp(actions: list[Action]) -> list[list[int]]:
    """Indices of ``actions`` grouped by grasp pose, in first-seen order."""
    groups: dict[bytes, list[int]] = {}
    for i, a in enumerate(actions):
        groups.setdefault(a.grasp_key(), []).append(i)
    return list(groups.values())
