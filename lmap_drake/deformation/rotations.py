"""The rotation R maximising tr(R^T M) (the ARAP local step), vectorised in
numpy: the SVD reference and warm-started Newton steps on SO(3) over unit
quaternions (w, x, y, z); the compiled lanes are ``arap_kernels.polar``."""
from __future__ import annotations

import numpy as np


def PolarRotationSvd(M: np.ndarray) -> np.ndarray:
    """Reference: the rotation (..., 3, 3) maximising tr(R^T M) by SVD, with
    the reflection fix (flip the singular vector of the smallest value)."""
    U, _, Vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(U @ Vt))
    d = np.where(d == 0, 1.0, d)
    U = U.copy()
    U[..., :, 2] *= d[..., None]
    return U @ Vt


def QuaternionToMatrix(q: np.ndarray) -> np.ndarray:
    """Unit quaternions (4, ...) as (w, x, y, z) -> rotations (3, 3, ...)
    (component-first layout, R[row, col])."""
    w, x, y, z = q
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    R = np.empty((3, 3) + w.shape)
    R[0, 0] = 1 - 2 * (yy + zz)
    R[0, 1] = 2 * (xy - wz)
    R[0, 2] = 2 * (xz + wy)
    R[1, 0] = 2 * (xy + wz)
    R[1, 1] = 1 - 2 * (xx + zz)
    R[1, 2] = 2 * (yz - wx)
    R[2, 0] = 2 * (xz - wy)
    R[2, 1] = 2 * (yz + wx)
    R[2, 2] = 1 - 2 * (xx + yy)
    return R


def MatrixToQuaternion(R: np.ndarray) -> np.ndarray:
    """Rotations (3, 3, ...) -> unit quaternions (4, ...) (w, x, y, z), w >= 0."""
    w = 0.5 * np.sqrt(np.maximum(1.0 + R[0, 0] + R[1, 1] + R[2, 2], 0.0))
    x = 0.5 * np.sqrt(np.maximum(1.0 + R[0, 0] - R[1, 1] - R[2, 2], 0.0))
    y = 0.5 * np.sqrt(np.maximum(1.0 - R[0, 0] + R[1, 1] - R[2, 2], 0.0))
    z = 0.5 * np.sqrt(np.maximum(1.0 - R[0, 0] - R[1, 1] + R[2, 2], 0.0))
    x = np.copysign(x, R[2, 1] - R[1, 2])
    y = np.copysign(y, R[0, 2] - R[2, 0])
    z = np.copysign(z, R[1, 0] - R[0, 1])
    q = np.stack([w, x, y, z])
    return q / np.sqrt((q * q).sum(axis=0))


def _NewtonStep(R, M, max_angle=1.0):
    """Rotation vector theta (3, N) of one Newton step for max tr(R'^T M) over
    R' = exp(theta^) R, flat (3, 3, N) arrays. With B = M R^T,
    f(theta) ~ tr B + theta.g - theta^T H theta / 2, g = axial(B - B^T),
    H = tr(B) I - sym(B). Where H is not positive definite (far from the
    optimum) the Mueller et al. (2016) step g / |tr B| is taken instead."""
    m = M
    r = R
    # B[i, j] = sum_c M[i, c] R[j, c]
    B = [[m[i, 0] * r[j, 0] + m[i, 1] * r[j, 1] + m[i, 2] * r[j, 2] for j in range(3)]
         for i in range(3)]
    gx, gy, gz = B[2][1] - B[1][2], B[0][2] - B[2][0], B[1][0] - B[0][1]
    tr = B[0][0] + B[1][1] + B[2][2]
    h00, h11, h22 = tr - B[0][0], tr - B[1][1], tr - B[2][2]
    h01, h02, h12 = -0.5 * (B[0][1] + B[1][0]), -0.5 * (B[0][2] + B[2][0]), -0.5 * (B[1][2] + B[2][1])
    c00 = h11 * h22 - h12 * h12
    c01 = h02 * h12 - h01 * h22
    c02 = h01 * h12 - h02 * h11
    c11 = h00 * h22 - h02 * h02
    c12 = h01 * h02 - h00 * h12
    c22 = h00 * h11 - h01 * h01
    det = h00 * c00 + h01 * c01 + h02 * c02
    pd = (h00 > 0) & (c22 > 0) & (det > 1e-12 * np.abs(tr) ** 3)
    inv = np.where(pd, 1.0 / np.where(pd, det, 1.0), 0.0)
    tx = (c00 * gx + c01 * gy + c02 * gz) * inv
    ty = (c01 * gx + c11 * gy + c12 * gz) * inv
    tz = (c02 * gx + c12 * gy + c22 * gz) * inv
    if not pd.all():
        mu = 1.0 / (np.abs(tr) + 1e-300)
        tx = np.where(pd, tx, gx * mu)
        ty = np.where(pd, ty, gy * mu)
        tz = np.where(pd, tz, gz * mu)
    ang = np.sqrt(tx * tx + ty * ty + tz * tz)
    big = ang > max_angle
    if big.any():
        sc = np.where(big, max_angle / np.where(big, ang, 1.0), 1.0)
        tx, ty, tz, ang = tx * sc, ty * sc, tz * sc, np.minimum(ang, max_angle)
    return tx, ty, tz, ang, pd


def PolarRotationQuaternion(M: np.ndarray, q: np.ndarray, max_iterations: int = 4,
                            tolerance: float = 1e-8, fallback_tolerance: float = 1e-6,
                            quadratic_tolerance: float = 1e-5
                            ) -> tuple[np.ndarray, np.ndarray]:
    """Rotation maximising tr(R^T M) for every M (3, 3, ...) (component-first
    layout): up to ``max_iterations`` Newton steps on SO(3) (``_NewtonStep``;
    the Mueller et al. 2016 step where the Hessian is not positive definite)
    from the unit quaternions ``q`` (4, ...) (warm start), then the SVD with
    the reflection fix for entries whose last step still exceeded
    ``fallback_tolerance`` rad. An entry stops when its step falls below
    ``tolerance`` rad, or after applying a Newton step (positive definite
    Hessian) below ``quadratic_tolerance`` rad, which leaves an error of the
    order of its square. Entries are independent, so stopping some early
    gives the same result as iterating all. Returns (R (3, 3, ...), q)."""
    shape = M.shape[2:]
    Mf = M.reshape(3, 3, -1)
    q = np.array(q, dtype=float).reshape(4, -1)
    R = QuaternionToMatrix(q)
    sel = None                                   # indices still iterating (None: all)
    Ms, Rs, qs = Mf, R, q
    for it in range(max_iterations + 1):
        ox, oy, oz, ang, pd = _NewtonStep(Rs, Ms)
        moving = ang > tolerance
        if not moving.all():
            if not moving.any():
                break
            ox, oy, oz, ang, pd = ox[moving], oy[moving], oz[moving], ang[moving], pd[moving]
            sel = np.flatnonzero(moving) if sel is None else sel[moving]
            Ms, qs = Mf[:, :, sel], q[:, sel]
        if it == max_iterations:
            bad = ang > fallback_tolerance
            if np.any(bad):
                sb = sel[bad] if sel is not None else np.flatnonzero(bad)
                Mb = np.moveaxis(Mf[:, :, sb], -1, 0)
                Rb = np.moveaxis(PolarRotationSvd(Mb), 0, -1)
                R[:, :, sb] = Rb
                q[:, sb] = MatrixToQuaternion(Rb)
            break
        half = 0.5 * ang
        sc = np.sinc(half / np.pi) * 0.5          # sin(ang/2) / ang
        dw, dx, dy, dz = np.cos(half), ox * sc, oy * sc, oz * sc
        w, x, y, z = qs
        qs = np.stack([dw * w - dx * x - dy * y - dz * z,
                       dw * x + dx * w + dy * z - dz * y,
                       dw * y - dx * z + dy * w + dz * x,
                       dw * z + dx * y - dy * x + dz * w])
        qs /= np.sqrt((qs * qs).sum(axis=0))
        Rs = QuaternionToMatrix(qs)
        if sel is None:
            q, R = qs, Rs
        else:
            q[:, sel] = qs
            R[:, :, sel] = Rs
        go = ~(pd & (ang <= quadratic_tolerance))
        if not go.all():
            if not go.any():
                break
            sel = np.flatnonzero(go) if sel is None else sel[go]
            Ms, qs, Rs = Mf[:, :, sel], q[:, sel], Rs[:, :, go]
    return R.reshape((3, 3) + shape), q.reshape((4,) + shape)
