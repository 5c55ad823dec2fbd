"""The ARAP energy E(x) = min_R E(x, R) and its gradient for the free
displacements x of every lane (covariances, polar rotations, L_ff x)."""
from __future__ import annotations

import numpy as np
from numba import njit

from lmap_drake.deformation.arap_kernels.jit import LEAF, OPTS
from lmap_drake.deformation.arap_kernels.polar import PolarLanes, PolarSvdLane


@njit(**LEAF)
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
        if PolarLanes(m9, q[i], Ri, act, ang, maxit, tol, ftol, qtol):
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


@njit(**OPTS)
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
        PolarSvdLane(m, 0, qq, Rl)
        new = 0.0
        for c in range(9):
            R9[i, c, l] = Rl[c, 0]
            new += Rl[c, 0] * m[c, 0]
        for c in range(4):
            q[i, c, l] = qq[c, 0]
        E[l] -= 2.0 * (new - old)
    for l in range(E.shape[0]):
        E[l] = max(E[l], 0.0)

@njit(**OPTS)
def EvaluateFrom(q0, nf, x, q, R, Lx, E, Mc, Ec, lin, cr, mptr, mcol, mwe, mw, deg,
                 maxit, tol, ftol, qtol, m3, m9, act, ang, tr, fb_node, fb_lane, fb_M):
    """``_Evaluate`` at x with the rotations warm-started from q0 (copied
    into q), then the SVD fallbacks applied (``_ApplyFallbacks``)."""
    q[:] = q0
    R9 = R.reshape((R.shape[0], 9, R.shape[2] // 3))
    nfb = _Evaluate(nf, x, q, R, R9, Lx, E, Mc, Ec, lin, cr, mptr, mcol, mwe, mw, deg,
                    maxit, tol, ftol, qtol, m3, m9, act, ang, tr, fb_node, fb_lane, fb_M)
    _ApplyFallbacks(nfb, fb_node, fb_lane, fb_M, q, R9, E)



@njit(**LEAF)
def Gradient(nf, R3, Lx, rc, cr, hptr, hcol, hwe, g):
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

