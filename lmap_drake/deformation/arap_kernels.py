"""Compiled (numba) kernels of the L-BFGS ARAP solver
(``ArapProblem.SolveAccelerated``; the maths is in ``arap.py``).

Actions are solved in ``nl`` lanes (``LANES``): per node, every array holds
its components times the lanes, lane last, so that each node or edge
operation is one vector loop over (component, lane). A lane takes the
next ready action as soon as its previous one stops (an action is ready
once the action it is warm-started from is solved), so the lanes stay busy
although actions need different iteration counts. Per action the iterates
are those of the batched numpy formulation, except that the per-node polar
rotations are warm-started from the predecessor action and the Newton
update uses the Cayley map (same fixed point, see ``_PolarLanes``).

Layouts, per node: vectors (3 nl) [k * nl + l]; quaternions (4 nl)
[c * nl + l]; 3 x 3 matrices (9 nl), column-major [(3 b + k) * nl + l] =
M[k, b]. The lane count is a run-time argument on purpose: numba leaves
SLP vectorisation off, and a constant trip count would be unrolled into
scalar code before the loop vectoriser runs.

Compiled with ``cache=True``: the first call after installing or editing
this file compiles for about 20 s and stores the machine code under
``__pycache__``; in later processes importing this module costs ~0.3 s
(numba) and the first call ~0.3 s (numba's one-time initialisation and
loading the cached code). Kernels release the GIL (grasps in threads).
"""
from __future__ import annotations

import numpy as np
from numba import njit

LANES = 8
# fastmath without "nnan"/"ninf": the solver compares against inf.
_OPTS = dict(cache=True, nogil=True, error_model="numpy",
             fastmath={"nsz", "arcp", "contract", "afn", "reassoc"})
# Leaf kernels neither allocate nor keep references: no reference counting
# (its atomic increments cost as much as the small kernels themselves).
_LEAF = dict(_OPTS, _nrt=False)


@njit(**_OPTS)
def _PolarSvdOne(m, l, q, R):
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


@njit(**_LEAF)
def _PolarLanes(m, q, R, act, ang_out, maxit, tol, ftol, qtol):
    """Rotation maximising tr(R^T M) per lane (M = m (9, nl)) by Newton steps
    on SO(3) from the warm start q (4, nl) (updated in place; R (9, nl) out).
    Same steps and stopping rules as ``arap.PolarRotationQuaternion``,
    except that a step theta is applied as the unit quaternion along
    (1, theta / 2) (Cayley map: angle 2 atan(|theta| / 2) = |theta| -
    |theta|^3 / 12 + ..., so convergence stays quadratic and the fixed point
    is the same). Returns the number of lanes still moving by more than
    ``ftol`` rad after ``maxit`` steps (ang_out[l] > ftol), for the SVD
    fallback (``_PolarSvdOne``)."""
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


@njit(**_OPTS)
def PolarRotations(M, q, nl, maxit, tol, ftol, qtol):
    """``_PolarLanes`` over a flat batch: M (N, 3, 3), q (N, 4) warm starts
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
        if _PolarLanes(m, qq, Rl, act, ang, maxit, tol, ftol, qtol):
            for l in range(nl):
                if ang[l] > ftol:
                    _PolarSvdOne(m, l, qq, Rl)
        for l in range(k):
            for a in range(3):
                for b in range(3):
                    R[s + l, a, b] = Rl[3 * b + a, l]
            for c in range(4):
                q[s + l, c] = qq[c, l]
    return R


@njit(**_LEAF)
def _Evaluate(nf, x, q, R3, R9, Lx, E, Mc, Ec, lin, cr, mptr, mcol, mwe, mw, deg,
              maxit, tol, ftol, qtol, m3, m9, act, ang, tr, fb_node, fb_lane, fb_M):
    """E(x) = min_R E(x, R) per lane at free displacements x (nf, 3 nl): the
    covariances of the active nodes (Mc (nr, 3, 3 nl) their constant part),
    their rotations (q (nr, 4, nl) warm start, updated; R3 (nr, 3, 3 nl) and
    R9 (nr, 9, nl), two views of the result), Lx = L_ff x (nf, 3 nl)
    (L_ff = diag(deg) - the free-free weights mw of the covariance rows), the
    traces tr (nl,) and E (nl,) (not clamped at 0). Scratch: m3 (3, 3 nl)
    and m9 (9, nl) views of one array. Entries left for the SVD fallback
    are listed in fb_node, fb_lane, fb_M (covariance, row-major); returns
    their number (see ``_ApplyFallbacks``)."""
    nr = Mc.shape[0]
    W3 = x.shape[1]
    nl = E.shape[0]
    nfb = 0
    for l in range(nl):
        tr[l] = 0.0
    for i in range(nr):
        for c in range(W3):
            m3[0, c] = Mc[i, 0, c]
            m3[1, c] = Mc[i, 1, c]
            m3[2, c] = Mc[i, 2, c]
        if i < nf:
            c0, c1, c2, dg = cr[i, 0], cr[i, 1], cr[i, 2], deg[i]
            for c in range(W3):
                xi = x[i, c]
                m3[0, c] += c0 * xi
                m3[1, c] += c1 * xi
                m3[2, c] += c2 * xi
                Lx[i, c] = dg * xi
            for p in range(mptr[i], mptr[i + 1]):
                j = mcol[p]
                w0, w1, w2, w = mwe[p, 0], mwe[p, 1], mwe[p, 2], mw[p]
                for c in range(W3):
                    xj = x[j, c]
                    m3[0, c] -= w0 * xj
                    m3[1, c] -= w1 * xj
                    m3[2, c] -= w2 * xj
                    Lx[i, c] -= w * xj
        else:
            for p in range(mptr[i], mptr[i + 1]):
                j = mcol[p]
                w0, w1, w2 = mwe[p, 0], mwe[p, 1], mwe[p, 2]
                for c in range(W3):
                    xj = x[j, c]
                    m3[0, c] -= w0 * xj
                    m3[1, c] -= w1 * xj
                    m3[2, c] -= w2 * xj
        Ri = R9[i]
        if _PolarLanes(m9, q[i], Ri, act, ang, maxit, tol, ftol, qtol):
            for l in range(nl):
                if ang[l] > ftol:
                    fb_node[nfb] = i
                    fb_lane[nfb] = l
                    for k in range(3):
                        for b in range(3):
                            fb_M[nfb, k, b] = m9[3 * b + k, l]
                    nfb += 1
        for s in range(9):
            for l in range(nl):
                tr[l] += Ri[s, l] * m9[s, l]
    for l in range(nl):
        E[l] = 0.0
    for i in range(nf):
        for k in range(3):
            o = k * nl
            for l in range(nl):
                E[l] += x[i, o + l] * (lin[i, o + l] + 2.0 * Lx[i, o + l])
    for l in range(nl):
        E[l] = Ec[l] + E[l] - 2.0 * tr[l]
    return nfb


@njit(**_OPTS)
def _ApplyFallbacks(nfb, fb_node, fb_lane, fb_M, q, R9, E):
    """SVD rotations for the entries listed by ``_Evaluate``, with their
    share of the energy E corrected; then E = max(E, 0)."""
    m = np.zeros((9, 1))
    qq = np.zeros((4, 1))
    Rl = np.zeros((9, 1))
    for f in range(nfb):
        i, l = fb_node[f], fb_lane[f]
        old = 0.0
        for k in range(3):
            for b in range(3):
                m[3 * b + k, 0] = fb_M[f, k, b]
                old += R9[i, 3 * b + k, l] * fb_M[f, k, b]
        _PolarSvdOne(m, 0, qq, Rl)
        new = 0.0
        for c in range(9):
            R9[i, c, l] = Rl[c, 0]
            new += Rl[c, 0] * m[c, 0]
        for c in range(4):
            q[i, c, l] = qq[c, 0]
        E[l] -= 2.0 * (new - old)
    for l in range(E.shape[0]):
        E[l] = max(E[l], 0.0)

@njit(**_OPTS)
def _EvaluateFrom(q0, nf, x, q, R, Lx, E, Mc, Ec, lin, cr, mptr, mcol, mwe, mw, deg,
                  maxit, tol, ftol, qtol, m3, m9, act, ang, tr, fb_node, fb_lane, fb_M):
    """``_Evaluate`` at x with the rotations warm-started from q0 (copied
    into q), then the SVD fallbacks applied (``_ApplyFallbacks``)."""
    q[:] = q0
    R9 = R.reshape((R.shape[0], 9, R.shape[2] // 3))
    nfb = _Evaluate(nf, x, q, R, R9, Lx, E, Mc, Ec, lin, cr, mptr, mcol, mwe, mw, deg,
                    maxit, tol, ftol, qtol, m3, m9, act, ang, tr, fb_node, fb_lane, fb_M)
    _ApplyFallbacks(nfb, fb_node, fb_lane, fb_M, q, R9, E)



@njit(**_LEAF)
def _Gradient(nf, R3, Lx, rc, cr, hptr, hcol, hwe, g):
    """grad E / 4 = L_ff x - rc - (R_i c_i + sum_j w_ij R_j e_ij) / 2, (nf, 3 nl)."""
    W3 = g.shape[1]
    for i in range(nf):
        c0, c1, c2 = cr[i, 0], cr[i, 1], cr[i, 2]
        for c in range(W3):
            g[i, c] = c0 * R3[i, 0, c] + c1 * R3[i, 1, c] + c2 * R3[i, 2, c]
        for p in range(hptr[i], hptr[i + 1]):
            j = hcol[p]
            w0, w1, w2 = hwe[p, 0], hwe[p, 1], hwe[p, 2]
            for c in range(W3):
                g[i, c] += w0 * R3[j, 0, c] + w1 * R3[j, 1, c] + w2 * R3[j, 2, c]
        for c in range(W3):
            g[i, c] = Lx[i, c] - rc[i, c] - 0.5 * g[i, c]


@njit(**_LEAF)
def _SolveLU(b, out, y, pr, pc, lp, li, lv, up, ui, uv, ud):
    """out = L_ff^-1 b for b (nf, w) with the sparse LU factors
    (Pr L_ff Pc = L U; strict triangles in CSC, ud = 1 / diag(U)),
    column-oriented substitutions."""
    n, w = b.shape
    for i in range(n):
        r = pr[i]
        for c in range(w):
            y[r, c] = b[i, c]
    for j in range(n):
        for p in range(lp[j], lp[j + 1]):
            i = li[p]
            v = lv[p]
            for c in range(w):
                y[i, c] -= v * y[j, c]
    for j in range(n - 1, -1, -1):
        d = ud[j]
        for c in range(w):
            y[j, c] *= d
        for p in range(up[j], up[j + 1]):
            i = ui[p]
            v = uv[p]
            for c in range(w):
                y[i, c] -= v * y[j, c]
    for i in range(n):
        r = pc[i]
        for c in range(w):
            out[i, c] = y[r, c]


@njit(**_LEAF)
def _Dot(a, b, out):
    """out[l] = sum_d a[d, l] b[d, l] for a, b (D, nl)."""
    D, nl = a.shape
    for l in range(nl):
        out[l] = 0.0
    d = 0
    while d + 4 <= D:
        for l in range(nl):
            out[l] += ((a[d, l] * b[d, l] + a[d + 1, l] * b[d + 1, l])
                       + (a[d + 2, l] * b[d + 2, l] + a[d + 3, l] * b[d + 3, l]))
        d += 4
    while d < D:
        for l in range(nl):
            out[l] += a[d, l] * b[d, l]
        d += 1


@njit(**_LEAF)
def _CopyLane(dst, src, l):
    """dst[:, l] = src[:, l] for (D, nl) arrays."""
    for d in range(dst.shape[0]):
        dst[d, l] = src[d, l]


@njit(**_LEAF)
def _Transpose(src, dst):
    """dst = src^T, (a, b) -> (b, a), eight rows of src at a time."""
    A, B = src.shape
    a0 = 0
    while a0 + 8 <= A:
        for b in range(B):
            dst[b, a0] = src[a0, b]
            dst[b, a0 + 1] = src[a0 + 1, b]
            dst[b, a0 + 2] = src[a0 + 2, b]
            dst[b, a0 + 3] = src[a0 + 3, b]
            dst[b, a0 + 4] = src[a0 + 4, b]
            dst[b, a0 + 5] = src[a0 + 5, b]
            dst[b, a0 + 6] = src[a0 + 6, b]
            dst[b, a0 + 7] = src[a0 + 7, b]
        a0 += 8
    for a in range(a0, A):
        for b in range(B):
            dst[b, a] = src[a, b]


@njit(**_LEAF)
def _TwoLoop(gT, qv, p, pT, ys, S, Y, rho, alpha, ring, m_, busy,
             pr, pc, lp, li, lv, up, ui, uv, ud):
    """L-BFGS direction -H g with the sparse L_ff^-1 as initial inverse
    Hessian, per lane: gT (nl, D) the gradients lane-major, S, Y (m, nl, D)
    the pairs (slot ring - 1 newest), rho (m, nl) (0: pair unused). Result
    p (nf, 3 nl) lane-last; qv, pT, ys scratch, alpha (m, nl) out. Lanes
    with busy[l] == 0 are skipped."""
    nl, D = gT.shape
    for l in range(nl):
        g = gT[l]
        if busy[l] == 0:
            continue
        for s_ in range(m_):
            j = (ring - 1 - s_) % m_
            r = rho[j, l]
            if r == 0.0:
                alpha[j, l] = 0.0
                continue
            Sj = S[j, l]
            acc = 0.0
            for d in range(D):
                acc += Sj[d] * g[d]
            a = r * acc
            alpha[j, l] = a
            Yj = Y[j, l]
            for d in range(D):
                g[d] -= a * Yj[d]
    _Transpose(gT, qv.reshape((D, nl)))
    _SolveLU(qv, p, ys, pr, pc, lp, li, lv, up, ui, uv, ud)
    _Transpose(p.reshape((D, nl)), pT)
    for l in range(nl):
        v = pT[l]
        if busy[l] == 0:
            continue
        for s_ in range(m_):
            j = (ring + s_) % m_
            r = rho[j, l]
            if r == 0.0:
                continue
            Yj = Y[j, l]
            acc = 0.0
            for d in range(D):
                acc += Yj[d] * v[d]
            c = alpha[j, l] - r * acc
            Sj = S[j, l]
            for d in range(D):
                v[d] += c * Sj[d]
        for d in range(D):
            v[d] = -v[d]
    _Transpose(pT, p.reshape((D, nl)))


@njit(**_OPTS)
def SolveTasks(nl, nf, cr, mptr, mcol, mwe, mw, deg, hptr, hcol, hwe,
               pr, pc, lp, li, lv, up, ui, uv, ud,
               Mc_t, rc_t, lin_t, b0_t, Ec_t, pred, ratio, order,
               max_iterations, rel_tol, floor, history, armijo, max_backtracks,
               pmaxit, ptol, pftol, pqtol,
               X_out, Q_out, R_out, E_out, it_out, conv_out):
    """L-BFGS (``ArapProblem.SolveAccelerated``) for T actions ("tasks") in
    ``nl`` lanes. Per task t: Mc_t (T, nr, 3, 3) the covariance part that
    does not depend on the free nodes, rc_t, lin_t (T, nf, 3), b0_t
    (T, nf, 3) the right-hand side of the Laplacian solve with R = I, Ec_t
    (T,) the energy constant; pred, ratio (T,): start from ratio times the
    solution of task pred (-1: from the Laplacian solve); ready tasks are
    taken in ``order``. Writes X_out (T, nf, 3), Q_out (T, nr, 4), R_out
    (T, nr, 3, 3), E_out, it_out, conv_out (T,)."""
    T, nr = Mc_t.shape[0], Mc_t.shape[1]
    D = 3 * nf
    m_ = history
    mh = max(m_, 1)
    W3 = 3 * nl
    # Vectors (nf, 3 nl) [i, k * nl + l], views (3 nf, nl); lane-major (nl, 3 nf).
    x = np.zeros((nf, W3))
    xn = np.zeros((nf, W3))
    xb = np.zeros((nf, W3))
    gr = np.zeros((nf, W3))
    grn = np.zeros((nf, W3))
    p = np.zeros((nf, W3))
    qv = np.zeros((nf, W3))
    ys = np.zeros((nf, W3))
    Lx = np.zeros((nf, W3))
    Lxn = np.zeros((nf, W3))
    Lxb = np.zeros((nf, W3))
    rc = np.zeros((nf, W3))
    lin = np.zeros((nf, W3))
    gT = np.zeros((nl, D))
    pT = np.zeros((nl, D))
    q = np.zeros((nr, 4, nl))
    q[:, 0, :] = 1.0
    qn = q.copy()
    qb = q.copy()
    # 3 x 3 matrices (nr, 3, 3 nl) [i, b, k * nl + l] = M_i[k, b]; views (nr, 9, nl).
    R = np.zeros((nr, 3, W3))
    Rn = np.zeros((nr, 3, W3))
    Rb = np.zeros((nr, 3, W3))
    Mc = np.zeros((nr, 3, W3))
    S = np.zeros((mh, nl, D))
    Y = np.zeros((mh, nl, D))
    rho = np.zeros((mh, nl))
    alpha = np.zeros((mh, nl))
    E = np.zeros(nl)
    En = np.zeros(nl)
    Eb = np.zeros(nl)
    Ep = np.full(nl, np.inf)
    Ec = np.zeros(nl)
    t = np.ones(nl)
    slope = np.zeros(nl)
    m3 = np.zeros((3, W3))
    m9 = m3.reshape((9, nl))
    act = np.zeros(nl)
    ang = np.zeros(nl)
    tr = np.zeros(nl)
    fb_node = np.zeros(nr * nl, np.int64)
    fb_lane = np.zeros(nr * nl, np.int64)
    fb_M = np.zeros((nr * nl, 3, 3))
    status = np.zeros(nl, np.int64)      # 0 idle, 1 starting, 2 iterating
    task = np.full(nl, -1, np.int64)
    its = np.zeros(nl, np.int64)
    tstat = np.zeros(T, np.int64)          # 0 pending, 1 running, 2 done
    fail = np.zeros(nl, np.bool_)
    ring = 0
    while True:
        # Stopping rule, then hand free lanes the next ready tasks.
        for l in range(nl):
            if status[l] == 2:
                done = E[l] <= floor or (Ep[l] < np.inf and
                                         Ep[l] - E[l] <= rel_tol * max(Ep[l], floor))
                if done or its[l] >= max_iterations:
                    k = task[l]
                    for i in range(nf):
                        for c in range(3):
                            X_out[k, i, c] = x[i, c * nl + l]
                    for i in range(nr):
                        for c in range(4):
                            Q_out[k, i, c] = q[i, c, l]
                        for a in range(3):
                            for b in range(3):
                                R_out[k, i, a, b] = R[i, b, a * nl + l]
                    E_out[k] = E[l]
                    it_out[k] = its[l]
                    conv_out[k] = done
                    tstat[k] = 2
                    status[l] = 0
        busy = 0
        for l in range(nl):
            if status[l] == 0:
                k = -1
                for o in range(T):
                    c = order[o]
                    if tstat[c] == 0 and (pred[c] < 0 or tstat[pred[c]] == 2):
                        k = c
                        break
                if k >= 0:
                    tstat[k] = 1
                    task[l] = k
                    status[l] = 1
                    Ec[l] = Ec_t[k]
                    rho[:, l] = 0.0
                    kp = pred[k]
                    for i in range(nr):
                        for a in range(3):
                            for b in range(3):
                                Mc[i, b, a * nl + l] = Mc_t[k, i, a, b]
                        for c in range(4):
                            q[i, c, l] = Q_out[kp, i, c] if kp >= 0 else (1.0 if c == 0 else 0.0)
                    for i in range(nf):
                        for c in range(3):
                            o = c * nl + l
                            rc[i, o] = rc_t[k, i, c]
                            lin[i, o] = lin_t[k, i, c]
                            x[i, o] = 0.0
            if status[l] != 0:
                busy += 1
        if busy == 0:
            break
        xV, xnV, pV = x.reshape((D, nl)), xn.reshape((D, nl)), p.reshape((D, nl))
        gV, gnV, xbV = gr.reshape((D, nl)), grn.reshape((D, nl)), xb.reshape((D, nl))
        # Direction. Starting lanes have no history (rho = 0); their "gradient"
        # -b0 gives p = L^-1 b0 (Laplacian solve), or p is the warm start.
        _Transpose(gV, gT)
        for l in range(nl):
            if status[l] == 1:
                k = task[l]
                for i in range(nf):
                    for c in range(3):
                        gT[l, 3 * i + c] = 0.0 if pred[k] >= 0 else -b0_t[k, i, c]
        # gT holds the gradient node-major per lane: [l, i * 3 + k]; the
        # lane-last vectors are [i, k * nl + l] = [(i * 3 + k) * nl + l].
        _TwoLoop(gT, qv, p, pT, ys, S, Y, rho, alpha, ring, m_, status,
                 pr, pc, lp, li, lv, up, ui, uv, ud)
        for l in range(nl):
            if status[l] == 1 and pred[task[l]] >= 0:
                k = task[l]
                for i in range(nf):
                    for c in range(3):
                        p[i, c * nl + l] = ratio[k] * X_out[pred[k], i, c]
        _Dot(gV, pV, slope)
        anybad = False
        for l in range(nl):
            fail[l] = status[l] == 2 and not (slope[l] < 0.0)
            anybad = anybad or fail[l]
        if anybad:                          # plain step, forget the history
            _SolveLU(gr, xb, ys, pr, pc, lp, li, lv, up, ui, uv, ud)
            for l in range(nl):
                if fail[l]:
                    rho[:, l] = 0.0
                    for d in range(D):
                        pV[d, l] = -xbV[d, l]
            _Dot(gV, pV, slope)
        # Trial point with Armijo backtracking.
        for d in range(D):
            for l in range(nl):
                xnV[d, l] = xV[d, l] + pV[d, l]
        _EvaluateFrom(q, nf, xn, qn, Rn, Lxn, En, Mc, Ec, lin, cr, mptr, mcol, mwe, mw, deg,
                      pmaxit, ptol, pftol, pqtol, m3, m9, act, ang, tr, fb_node, fb_lane, fb_M)
        for l in range(nl):
            t[l] = 1.0
        for _ in range(max_backtracks):
            anyf = False
            for l in range(nl):
                fail[l] = status[l] == 2 and not (En[l] <= E[l] + 4.0 * armijo * t[l] * slope[l])
                if fail[l]:
                    t[l] *= 0.5
                    anyf = True
            if not anyf:
                break
            for d in range(D):
                for l in range(nl):
                    xbV[d, l] = xV[d, l] + t[l] * pV[d, l]
            _EvaluateFrom(q, nf, xb, qb, Rb, Lxb, Eb, Mc, Ec, lin, cr, mptr, mcol, mwe, mw,
                          deg, pmaxit, ptol, pftol, pqtol, m3, m9, act, ang, tr, fb_node,
                          fb_lane, fb_M)
            for l in range(nl):
                if fail[l]:
                    _CopyLane(xnV, xbV, l)
                    _CopyLane(qn.reshape((4 * nr, nl)), qb.reshape((4 * nr, nl)), l)
                    _CopyLane(Rn.reshape((9 * nr, nl)), Rb.reshape((9 * nr, nl)), l)
                    _CopyLane(Lxn.reshape((D, nl)), Lxb.reshape((D, nl)), l)
                    En[l] = Eb[l]
        for l in range(nl):
            if status[l] == 2 and not (En[l] <= E[l]):     # keep the old iterate
                _CopyLane(xnV, xV, l)
                _CopyLane(qn.reshape((4 * nr, nl)), q.reshape((4 * nr, nl)), l)
                _CopyLane(Rn.reshape((9 * nr, nl)), R.reshape((9 * nr, nl)), l)
                _CopyLane(Lxn.reshape((D, nl)), Lx.reshape((D, nl)), l)
                En[l] = E[l]
                rho[:, l] = 0.0
        _Gradient(nf, Rn, Lxn, rc, cr, hptr, hcol, hwe, grn)
        # History pair (s, y), lane-major; none for starting lanes.
        if m_ > 0:
            Sr, Yr = S[ring], Y[ring]
            for d in range(D):
                for l in range(nl):
                    Sr[l, d] = xnV[d, l] - xV[d, l]
                    Yr[l, d] = gnV[d, l] - gV[d, l]
            for l in range(nl):
                sy = 0.0
                ss = 0.0
                yy = 0.0
                Sl, Yl = Sr[l], Yr[l]
                for d in range(D):
                    sy += Sl[d] * Yl[d]
                    ss += Sl[d] * Sl[d]
                    yy += Yl[d] * Yl[d]
                ok = status[l] == 2 and sy > 1e-12 * np.sqrt(ss * yy)
                rho[ring, l] = 1.0 / sy if ok else 0.0
            ring = (ring + 1) % m_
        x, xn = xn, x
        q, qn = qn, q
        R, Rn = Rn, R
        Lx, Lxn = Lxn, Lx
        gr, grn = grn, gr
        for l in range(nl):
            if status[l] == 2:
                Ep[l] = E[l]
                its[l] += 1
            elif status[l] == 1:
                Ep[l] = np.inf
                its[l] = 1
                status[l] = 2
            E[l] = En[l]
