"""Value checks shared by every section's validation (``Validate*Config``
beside each config dataclass): rules per key, enumerations, finiteness.

Rules: ">0", ">=0", ">=1", "(lo,hi)" / "[lo,hi]" (open / closed ends),
"finite"; "Nx<rule>" = a list of N values each obeying <rule>, "+x<rule>" =
a non-empty list. Poses: ``CheckTransform`` / ``TransformError`` (finite,
rotation orthonormal with det +1), the one check for every pose (scenario,
calibration file, recording). Failures raise ``ConfigError(key, detail)``; the scenario
loader adds where the key was set.

Floor module: imports only numpy, pydrake and ``lmap_drake.errors``.
"""
from __future__ import annotations

import dataclasses as dc
import re
import typing

import numpy as np
from pydrake.common.schema import Transform

from lmap_drake.errors import ConfigError


def Join(path: str, key: str) -> str:
    """``path.key`` (``key`` alone when ``path`` is empty)."""
    return f"{path}.{key}" if path else key


def Need(cond, key: str, detail: str) -> None:
    """Raises ``ConfigError(key, detail)`` unless ``cond``."""
    if not cond:
        raise ConfigError(key, detail)


def GetPath(obj, path: str):
    """``obj.a.b`` for ``path`` ``"a.b"``."""
    for part in path.split("."):
        obj = getattr(obj, part)
    return obj


def IsNumber(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool)


def IsFiniteNumber(v) -> bool:
    """A number (not a bool) that is finite."""
    return IsNumber(v) and bool(np.isfinite(v))


def RuleError(v, rule: str) -> str:
    """'' if the scalar ``v`` obeys ``rule``, else what is wrong."""
    if not IsNumber(v):
        return f"must be a number, got {v!r}"
    if not np.isfinite(v):
        return f"must be finite, got {v}"
    if rule == "finite":
        return ""
    if rule.startswith(">="):
        lo = float(rule[2:])
        return "" if v >= lo else f"must be >= {rule[2:]}, got {v}"
    if rule.startswith(">"):
        lo = float(rule[1:])
        return "" if v > lo else f"must be > {rule[1:]}, got {v}"
    lo_s, hi_s = rule[1:-1].split(",")
    lo, hi = float(lo_s), float(hi_s)
    ok = (v > lo if rule[0] == "(" else v >= lo) and (v < hi if rule[-1] == ")" else v <= hi)
    return "" if ok else f"must be in {rule}, got {v}"


# How far a pose's rotation may be from orthonormal (max |R^T R - I|, |det R - 1|).
RIGID_TOLERANCE = 1e-6


def RigidMatrixError(M) -> str:
    """'' when ``M`` (a 4x4 homogeneous matrix) is a rigid transform: finite,
    rotation orthonormal with det +1 within ``RIGID_TOLERANCE``, bottom row
    [0, 0, 0, 1]; else what is wrong (one phrase)."""
    try:
        M = np.asarray(M, dtype=float)
    except (TypeError, ValueError):
        return "must be a 4x4 matrix of numbers"
    if M.shape != (4, 4):
        return f"must be a 4x4 matrix, got shape {M.shape}"
    if not np.all(np.isfinite(M)):
        return "must be finite (translation and rotation)"
    if np.abs(M[3] - [0.0, 0.0, 0.0, 1.0]).max() > RIGID_TOLERANCE:
        return f"must have the bottom row [0, 0, 0, 1], got {M[3].tolist()}"
    R = M[:3, :3]
    off = float(np.abs(R.T @ R - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if off > RIGID_TOLERANCE or abs(det - 1.0) > RIGID_TOLERANCE:
        return (f"must be a rigid pose: its rotation is not orthonormal with det +1 "
                f"(max |R^T R - I| = {off:.3g}, det = {det:.3g}; an AngleAxis needs a "
                f"non-zero axis)")
    return ""


def TransformError(X) -> str:
    """'' when ``X`` (a ``pydrake.common.schema.Transform``, a
    ``RigidTransform`` or a 4x4 matrix) is a rigid pose (see
    ``RigidMatrixError``); a random schema Transform is checked for a zero
    AngleAxis axis only. Else what is wrong."""
    if isinstance(X, Transform):
        if not X.IsDeterministic():
            axis = getattr(X.rotation.value, "axis", None)
            if isinstance(axis, np.ndarray) and axis.shape == (3,) and (
                    not np.all(np.isfinite(axis)) or np.linalg.norm(axis) < 1e-9):
                return "must be a rigid pose: its AngleAxis axis must be finite and non-zero"
            return ""
        try:
            X = X.GetDeterministicValue()
        except Exception:  # noqa: BLE001 - Drake refuses a non-finite rotation
            return "must be finite (translation and rotation)"
    if hasattr(X, "GetAsMatrix4"):
        X = X.GetAsMatrix4()
    return RigidMatrixError(X)


def FiniteTransform(X) -> bool:
    """``X`` is a rigid pose (finite, orthonormal rotation; see ``TransformError``)."""
    return not TransformError(X)


def CheckTransform(X, key: str) -> None:
    """Raises ``ConfigError(key, ...)`` unless ``X`` is a rigid pose."""
    err = TransformError(X)
    if err:
        raise ConfigError(key, err)


def CheckFinite(obj, path: str = "") -> None:
    """Every number (and pose) of the dataclass ``obj``, nested ones
    included, is finite (NaN passes comparisons)."""
    for f in dc.fields(obj):
        v = getattr(obj, f.name)
        p = Join(path, f.name)
        if dc.is_dataclass(v):
            CheckFinite(v, p)
        elif IsNumber(v) and not np.isfinite(v):
            raise ConfigError(p, f"must be finite, got {v}")
        elif isinstance(v, (list, tuple)):
            for i, x in enumerate(v):
                if IsNumber(x) and not np.isfinite(x):
                    raise ConfigError(p, f"must be finite, got {list(v)} (item {i})")
        elif isinstance(v, Transform):
            CheckTransform(v, p)


def CheckRules(cfg, path: str, rules: typing.Mapping[str, str],
               enums: typing.Mapping[str, tuple] = {}) -> None:
    """``CheckFinite``, then each key of ``rules`` (relative to ``cfg``,
    dotted) against its rule, then each key of ``enums`` against its
    choices; key paths in errors start with ``path``."""
    CheckFinite(cfg, path)
    for key, rule in rules.items():
        v = GetPath(cfg, key)
        full = Join(path, key)
        m = re.fullmatch(r"(\d+|\+)x(.*)", rule)
        if m:
            n, item = m.groups()
            if not isinstance(v, (list, tuple)):
                raise ConfigError(full, f"must be a list, got {v!r}")
            if n == "+":
                Need(len(v) >= 1, full, f"needs at least one value, got {list(v)}")
            else:
                Need(len(v) == int(n), full, f"needs {n} values, got {len(v)}: {list(v)}")
            for x in v:
                err = RuleError(x, item)
                if err:
                    raise ConfigError(
                        full, f"values {err.replace('must', 'must each')} in {list(v)}")
        else:
            err = RuleError(v, rule)
            if err:
                raise ConfigError(full, err)
    for key, choices in enums.items():
        v = GetPath(cfg, key)
        Need(v in choices, Join(path, key),
             f"'{v}' unknown; choose one of {', '.join(choices)}")
