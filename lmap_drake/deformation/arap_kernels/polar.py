"""Per-node polar rotations in lanes: the rotation maximising tr(R^T M)
by warm-started Newton steps on SO(3) (Cayley update), with the SVD as
fallback; matrices (9, nl) column-major, quaternions (4, nl) (w, x, y, z)."""
from __future__ import annotations

import numpy as np
from numba import njit

from lmap_drake.deformation.arap_kernels.jit import LEAF, OPTS


@njit(**OPTS)
def PolarSvdLane(m, l, q, R):
    """SVD fallback for lane ``l``: R = U diag(1, 1, det) V^T of M (from
    m (9, nl)), and its quaternion (w >= 0)."""
    A = np.empty((3, 3))
    for k in range(3):
        for b in range(3):
            A[k, b] = m[3 * b + k, l]
    U, _, Vt = np.linalg.svd(A)
    if np.linalg.det(U @ Vt) < 0.0:
        for k in range(3):
            U[k, 2] = -U[k, 2]
    Rm = U @ Vt
    for k in range(3):
        for b in range(3):
            R[3 * b + k, l] = Rm[k, b]
    w = 0.5 * np.sqrt(max(1.0 + Rm[0, 0] + Rm[1, 1] + Rm[2, 2], 0.0))
    x = 0.5 * np.sqrt(max(1.0 + Rm[0, 0] - Rm[1, 1] - Rm[2, 2], 0.0))
    y = 0.5 * np.sqrt(max(1.0 - Rm[0, 0] + Rm[1, 1] - Rm[2, 2], 0.0))
    z = 0.5 * np.sqrt(max(1.0 - Rm[0, 0] - Rm[1, 1] + Rm[2, 2], 0.0))
    x = x if Rm[2, 1] - Rm[1, 2] >= 0.0 else -x
    y = y if Rm[0, 2] - Rm[2, 0] >= 0.0 else -y
    z = z if Rm[1, 0] - Rm[0, 1] >= 0.0 else -z
    s = 1.0 / np.sqrt(w * w + x * x + y * y + z * z)
    q[0, l], q[1, l], q[2, l], q[3, l] = w * s, x * s, y * s, z * s


@njit(**LEAF)
def PolarLanes(m, q, R, act, ang_out, maxit, tol, ftol, qtol):
    """Rotation maximising tr(R^T M) per lane (M = m (9, nl)) by Newton steps
    on SO(3) from the warm start q (4, nl) (updated in place; R (9, nl) out).
    Same steps and stopping rules as ``rotations.PolarRotationQuaternion``,
    except that a step theta is applied as the unit quaternion along
    (1, theta / 2) (Cayley map: angle 2 atan(|theta| / 2) = |theta| -
    |theta|^3 / 12 + ..., so convergence stays quadratic and the fixed point
    is the same). Returns the number of lanes still moving by more than
    ``ftol`` rad after ``maxit`` steps (ang_out[l] > ftol), for the SVD
    fallback (``PolarSvdLane``)."""
    nl = m.shape[1]
    for l in range(nl):
        act[l] = 1.0
        ang_out[l] = 0.0
    nact = 1.0
    checked = False
    for it in range(maxit + 1):
        if nact == 0.0:
            break
        last = it == maxit
        checked = last
        nact = 0.0
        for l in range(nl):
            w, x, y, z = q[0, l], q[1, l], q[2, l], q[3, l]
            r00 = 1.0 - 2.0 * (y * y + z * z)
            r01 = 2.0 * (x * y - w * z)
            r02 = 2.0 * (x * z + w * y)
            r10 = 2.0 * (x * y + w * z)
            r11 = 1.0 - 2.0 * (x * x + z * z)
            r12 = 2.0 * (y * z - w * x)
            r20 = 2.0 * (x * z - w * y)
            r21 = 2.0 * (y * z + w * x)
            r22 = 1.0 - 2.0 * (x * x + y * y)
            m00, m10, m20 = m[0, l], m[1, l], m[2, l]
            m01, m11, m21 = m[3, l], m[4, l], m[5, l]
            m02, m12, m22 = m[6, l], m[7, l], m[8, l]
            # B = M R^T
            b00 = m00 * r00 + m01 * r01 + m02 * r02
            b01 = m00 * r10 + m01 * r11 + m02 * r12
            b02 = m00 * r20 + m01 * r21 + m02 * r22
            b10 = m10 * r00 + m11 * r01 + m12 * r02
            b11 = m10 * r10 + m11 * r11 + m12 * r12
            b12 = m10 * r20 + m11 * r21 + m12 * r22
            b20 = m20 * r00 + m21 * r01 + m22 * r02
            b21 = m20 * r10 + m21 * r11 + m22 * r12
            b22 = m20 * r20 + m21 * r21 + m22 * r22
            gx, gy, gz = b21 - b12, b02 - b20, b10 - b01
            tr = b00 + b11 + b22
            h00, h11, h22 = tr - b00, tr - b11, tr - b22
            h01, h02, h12 = -0.5 * (b01 + b10), -0.5 * (b02 + b20), -0.5 * (b12 + b21)
            c00 = h11 * h22 - h12 * h12
            c01 = h02 * h12 - h01 * h22
            c02 = h01 * h12 - h02 * h11
            c11 = h00 * h22 - h02 * h02
            c12 = h01 * h02 - h00 * h12
            c22 = h00 * h11 - h01 * h01
            det = h00 * c00 + h01 * c01 + h02 * c02
            atr = abs(tr)
            pd = (h00 > 0.0) & (c22 > 0.0) & (det > 1e-12 * atr * atr * atr)
            inv = 1.0 / det if pd else 0.0
            mu = 0.0 if pd else 1.0 / (atr + 1e-300)
            tx = (c00 * gx + c01 * gy + c02 * gz) * inv + gx * mu
            ty = (c01 * gx + c11 * gy + c12 * gz) * inv + gy * mu
            tz = (c02 * gx + c12 * gy + c22 * gz) * inv + gz * mu
            ang = np.sqrt(tx * tx + ty * ty + tz * tz)
            sc = 1.0 / ang if ang > 1.0 else 1.0
            ang = min(ang, 1.0)
            mv = (act[l] > 0.0) & (ang > tol)
            if last:
                ang_out[l] = ang if mv else 0.0
                act[l] = 0.0
            else:
                h = 0.5 * sc if mv else 0.0
                dx, dy, dz = tx * h, ty * h, tz * h
                nw = w - dx * x - dy * y - dz * z
                nx = x + dx * w + dy * z - dz * y
                ny = y - dx * z + dy * w + dz * x
                nz = z + dx * y - dy * x + dz * w
                s = 1.0 / np.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
                q[0, l] = nw * s
                q[1, l] = nx * s
                q[2, l] = ny * s
                q[3, l] = nz * s
                a = 1.0 if mv else 0.0
                a = 0.0 if pd & (ang <= qtol) else a
                act[l] = a
                nact += a
    for l in range(nl):
        w, x, y, z = q[0, l], q[1, l], q[2, l], q[3, l]
        R[0, l] = 1.0 - 2.0 * (y * y + z * z)
        R[3, l] = 2.0 * (x * y - w * z)
        R[6, l] = 2.0 * (x * z + w * y)
        R[1, l] = 2.0 * (x * y + w * z)
        R[4, l] = 1.0 - 2.0 * (x * x + z * z)
        R[7, l] = 2.0 * (y * z - w * x)
        R[2, l] = 2.0 * (x * z - w * y)
        R[5, l] = 2.0 * (y * z + w * x)
        R[8, l] = 1.0 - 2.0 * (x * x + y * y)
    nfb = 0
    if checked:                          # the check step ran: lanes for the SVD
        for l in range(nl):
            nfb += ang_out[l] > ftol
    return nfb


@njit(**OPTS)
def PolarRotations(M, q, nl, maxit, tol, ftol, qtol):
    """``PolarLanes`` over a flat batch: M (N, 3, 3), q (N, 4) warm starts
    (updated in place). Returns R (N, 3, 3)."""
    N = M.shape[0]
    R = np.empty((N, 3, 3))
    m = np.zeros((9, nl))
    qq = np.zeros((4, nl))
    Rl = np.empty((9, nl))
    act = np.empty(nl)
    ang = np.empty(nl)
    for s in range(0, N, nl):
        k = min(nl, N - s)
        for l in range(nl):
            for a in range(3):
                for b in range(3):
                    m[3 * b + a, l] = M[s + l, a, b] if l < k else 0.0
            for c in range(4):
                qq[c, l] = q[s + l, c] if l < k else (1.0 if c == 0 else 0.0)
        if PolarLanes(m, qq, Rl, act, ang, maxit, tol, ftol, qtol):
            for l in range(nl):
                if ang[l] > ftol:
                    PolarSvdLane(m, l, qq, Rl)
        for l in range(k):
            for a in range(3):
                for b in range(3):
                    R[s + l, a, b] = Rl[3 * b + a, l]
            for c in range(4):
                q[s + l, c] = qq[c, l]
    return R
