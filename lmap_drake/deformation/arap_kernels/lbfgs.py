"""The L-BFGS driver (``SolveTasks``): lane scheduling, the two-loop
direction with L_ff^-1 (sparse LU substitutions) as initial inverse
Hessian, Armijo backtracking and the history pairs."""
from __future__ import annotations

import numpy as np
from numba import njit

from lmap_drake.deformation.arap_kernels.energy import EvaluateFrom, Gradient
from lmap_drake.deformation.arap_kernels.jit import LEAF, OPTS


@njit(**LEAF)
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


@njit(**LEAF)
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


@njit(**LEAF)
def _CopyLane(dst, src, l):
    """dst[:, l] = src[:, l] for (D, nl) arrays."""
    for d in range(dst.shape[0]):
        dst[d, l] = src[d, l]


@njit(**LEAF)
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


@njit(**LEAF)
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


@njit(**OPTS)
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
        EvaluateFrom(q, nf, xn, qn, Rn, Lxn, En, Mc, Ec, lin, cr, mptr, mcol, mwe, mw, deg,
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
            EvaluateFrom(q, nf, xb, qb, Rb, Lxb, Eb, Mc, Ec, lin, cr, mptr, mcol, mwe, mw,
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
        Gradient(nf, Rn, Lxn, rc, cr, hptr, hcol, hwe, grn)
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
