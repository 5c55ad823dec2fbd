"""As-rigid-as-possible deformation (Sorkine & Alexa 2007) on a point graph,
batched over actions. World frame W, metres.

Energy, with one rotation R_i per node and each undirected edge counted
from both ends (as in Sorkine 2007):

    E = sum_i sum_{j in N(i)} w_ij |(x'_i - x'_j) - R_i (x_i - x_j)|^2.

The first ``num_free`` nodes are free; the others are constrained to given
displacements. Global step: L_ff u_f = b_f - L_fc u_c, with the weighted
graph Laplacian L factorised once per graph and all actions solved as
right-hand sides of one solve. Local step: per node and action, R_i = the
rotation maximising tr(R^T M_i), M_i = sum_j w_ij e'_ij e_ij^T, by
warm-started Newton steps on SO(3) (``rotations.PolarRotationQuaternion``),
vectorised over all nodes and actions; the result is always a proper
rotation, so the reflection case is handled by construction (same answer
as the SVD with the sign fix, see ``rotations.PolarRotationSvd``).

Solvers (``ArapProblem.Solve(method=...)``), same energy, constraints,
start (R = I, i.e. the first iterate is the Laplacian solve) and stopping
rule (relative energy decrease of one iteration below a tolerance):

- "plain": the textbook alternation of local and global steps. It is a
  descent method with the Laplacian as a fixed preconditioner: the global
  step from x is x - L_ff^-1 grad E(x) / 4 (grad E(x) = 4 (L_ff x - b(R(x)))
  with the rotations optimal for x).
- "lbfgs" (default): L-BFGS on E(x) = min_R E(x, R) with L_ff as the
  initial Hessian (Liu, Bouaziz & Kavan 2017), Armijo backtracking, and the
  plain step whenever the L-BFGS direction is not a descent direction. One
  global solve (L_ff^-1 on the two-loop vector) and one local step per
  iteration, as the plain solver, but far fewer iterations for the same
  energy. Rotations are kept only for the free nodes and the constrained
  nodes with a free neighbour; the other constrained nodes have a constant
  covariance per action, so their rotations and energy share are computed
  once per solve. Runs compiled (numba, ``arap_kernels``): actions in SIMD
  lanes, each lane taking the next ready action when its own stops, L_ff^-1
  by sparse LU substitutions. Per action the iterates are those of the
  former vectorised numpy implementation up to round-off and the polar
  warm start (energies within ~1e-6 relative, same iteration counts on the
  benchmark leaf); at the default tolerance 1e-5 the energies are within
  ~1e-4 of the tight minimum (the plain solver: ~5e-4), see
  tests/deformation/test_arap_kernels.py.
"""
from __future__ import annotations

import contextlib
import ctypes
import dataclasses as dc
import glob
import os

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from lmap_drake.deformation import arap_kernels as K
from lmap_drake.deformation.rotations import PolarRotationQuaternion


def _OpenBlasLocalThreads() -> list:
    """``openblas_set_num_threads_local`` (thread count for the calling
    thread only) of the OpenBLAS copies bundled with numpy and scipy."""
    import scipy
    out = []
    for pkg in (np, scipy):
        for path in sorted(glob.glob(os.path.join(os.path.dirname(pkg.__file__) + ".libs",
                                                  "*openblas*"))):
            try:
                fn = getattr(ctypes.CDLL(path), "openblas_set_num_threads_local", None)
            except OSError:
                fn = None
            if fn is not None:
                fn.argtypes, fn.restype = [ctypes.c_int], ctypes.c_int
                out.append(fn)
    return out


_SET_LOCAL_THREADS = _OpenBlasLocalThreads()


@contextlib.contextmanager
def SingleThreadBlas():
    """Runs the block with one BLAS thread in the calling thread. The
    solver's products (~600 x 600 times ~600 x 170) and factorisations are
    too small to gain from threads, and on a shared machine OpenBLAS worker
    threads waiting for a core made them 3-100x slower (measured: the
    dense inverse of one grasp 4 s instead of 0.04 s). No-op where the
    bundled OpenBLAS lacks per-thread settings."""
    prev = [fn(1) for fn in _SET_LOCAL_THREADS]
    try:
        yield
    finally:
        for fn, p in zip(_SET_LOCAL_THREADS, prev):
            fn(p)


@dc.dataclass
class ArapResult:
    """Per action a: ``displacements`` / ``positions_W`` (A, n, 3) m,
    ``rotations`` (A, n, 3, 3), minimised ``energy`` (A,) m^2, ``iterations``
    (A,) global-local iterations, ``converged`` (A,) relative energy
    decrease fell below the tolerance before ``max_iterations``."""
    displacements: np.ndarray
    positions_W: np.ndarray
    rotations: np.ndarray
    energy: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray


def _DistanceChains(dU_c: np.ndarray):
    """For actions (A, nc, 3): ``pred`` (A,) the action with the next smaller
    positive multiple of the same constrained displacements (-1 if none),
    ``ratio`` (A,) the scale factor from it, and the stages (lists of
    action indices) in which to solve them so that ``pred`` is solved first."""
    A = len(dU_c)
    v = dU_c.reshape(A, -1) if A else np.zeros((0, 1))
    s = np.linalg.norm(v, axis=1)
    pred, ratio = np.full(A, -1), np.ones(A)
    nz = np.flatnonzero(s > 0)
    if len(nz):
        d = np.round(v[nz] / s[nz, None], 9) + 0.0              # + 0.0: no -0.0
        groups: dict[bytes, list[int]] = {}
        for a, row in zip(nz, d):
            groups.setdefault(row.tobytes(), []).append(a)
        for mem in groups.values():
            mem = np.array(mem)
            mem = mem[np.argsort(s[mem], kind="stable")]
            for a, b in zip(mem[:-1], mem[1:]):
                r = s[b] / s[a]
                if r > 1.0 + 1e-9 and np.abs(v[b] - r * v[a]).max() <= 1e-9 * s[b]:
                    pred[b], ratio[b] = a, r
    depth = np.zeros(A, dtype=np.int64)
    for a in np.argsort(s, kind="stable"):
        if pred[a] >= 0:
            depth[a] = depth[pred[a]] + 1
    return pred, ratio, [np.flatnonzero(depth == k) for k in range(depth.max() + 1 if A else 0)]


class ArapProblem:
    """ARAP on a fixed graph: ``rest_W`` (n, 3) with the first ``num_free``
    nodes free, undirected ``edges`` (m, 2) with ``weights`` (m,).
    ``factorization`` is how the plain solver solves with the free-node
    Laplacian L_ff ("splu" sparse LU, "cholesky" dense Cholesky, "inverse"
    dense inverse; built on its first use); the L-BFGS solver always uses
    the sparse LU of L_ff, computed here."""

    def __init__(self, rest_W: np.ndarray, edges: np.ndarray, weights: np.ndarray,
                 num_free: int, factorization: str = "inverse", polar_iterations: int = 4):
        rest = np.asarray(rest_W, dtype=float)
        n = len(rest)
        nf = int(num_free)
        if nf <= 0 or nf >= n:
            raise ValueError(f"need free and constrained nodes, got {nf} free of {n}")
        if factorization not in ("splu", "cholesky", "inverse"):
            raise ValueError(f"unknown factorization '{factorization}'")
        edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
        w = np.asarray(weights, dtype=float)
        src = np.concatenate([edges[:, 0], edges[:, 1]])
        dst = np.concatenate([edges[:, 1], edges[:, 0]])
        w2 = np.concatenate([w, w])
        e = rest[src] - rest[dst]                                    # (2m, 3)
        self.rest_W, self.n, self.num_free = rest, n, nf
        self.polar_iterations = int(polar_iterations)
        self.edges, self.weights = edges, w
        self.factorization = factorization
        deg = np.bincount(src, w2, minlength=n)
        if np.any(deg[:nf] == 0):
            raise ValueError("free node without edges")
        L = sp.csr_matrix((np.concatenate([-w2, deg]),
                           (np.concatenate([src, np.arange(n)]), np.concatenate([dst, np.arange(n)]))),
                          shape=(n, n))
        self.L = L
        self._L_ff = L[:nf, :nf].tocsr()
        self.L_fc = L[:nf, nf:].tocsr()
        self._L_cc = L[nf:, nf:].tocsr()
        self._edge_data = (src, dst, w2, e)
        self._solve_plain = None
        self._plain_ops = None
        self._c = np.stack([np.bincount(src, w2 * e[:, b], minlength=n)
                            for b in range(3)], axis=1)              # sum_j w e_ij
        self._cT = np.ascontiguousarray(self._c.T)
        self._M0 = np.stack([np.stack([np.bincount(src, w2 * e[:, k] * e[:, b], minlength=n)
                                       for b in range(3)]) for k in range(3)])[..., None]
        self._e2 = float((w2 * (e * e).sum(1)).sum())
        self._BuildKernelOperators(src, dst, w2, e)

    # ---- the L_ff solve of the plain solver.

    def _solve(self, b: np.ndarray) -> np.ndarray:
        if self._solve_plain is None:
            with SingleThreadBlas():
                self._solve_plain = self._Factorize(self._L_ff, self.factorization)
        return self._solve_plain(b)

    @staticmethod
    def _Factorize(L_ff, factorization: str):
        if factorization == "splu":
            lu = spla.splu(L_ff.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                           options=dict(SymmetricMode=True))
            return lu.solve
        if factorization == "cholesky":
            cf = sla.cho_factor(L_ff.toarray(), lower=False, check_finite=False)
            return lambda b: sla.cho_solve(cf, b, check_finite=False)
        # Dense inverse from the Cholesky factor (LAPACK potrf + potri).
        c, info = sla.lapack.dpotrf(L_ff.toarray(), lower=False)
        inv, info2 = sla.lapack.dpotri(c, lower=False)
        if info or info2:
            raise ValueError("free-node Laplacian is not positive definite")
        inv = np.triu(inv) + np.triu(inv, 1).T
        return lambda b: inv @ b

    def _PlainOperators(self):
        """K_b[i, j] = w_ij e_ij[b]; Kv = [K_0; K_1; K_2] (3n x n), Kh = [K_0 K_1 K_2]."""
        if self._plain_ops is None:
            src, dst, w2, e = self._edge_data
            n = self.n
            val = np.concatenate([w2 * e[:, b] for b in range(3)])
            Kv = sp.csr_matrix((val, (np.concatenate([src + b * n for b in range(3)]),
                                      np.tile(dst, 3))), shape=(3 * n, n))
            Kh = sp.csr_matrix((val, (np.tile(src, 3),
                                      np.concatenate([dst + b * n for b in range(3)]))),
                               shape=(n, 3 * n))
            self._plain_ops = (Kv, Kh, self.L @ self.rest_W)
        return self._plain_ops

    # ---- operators of the compiled L-BFGS solver (arap_kernels.SolveTasks).

    def _BuildKernelOperators(self, src, dst, w2, e) -> None:
        """Rotations are kept only for the "active" nodes: the free nodes
        then the constrained nodes with a free neighbour. A constrained node
        with only constrained neighbours has a constant covariance per
        action, so its rotation and its share of the energy are computed
        once per solve. CSR arrays (row pointer, column, w_ij e_ij (., 3)):
        ``_mrows`` active rows i, free columns j (covariances
        M_i = Mconst_i + x_i c_i^T - sum_j w_ij x_j e_ij^T), with w_ij and the
        free nodes' degrees (L_ff x); ``_hrows`` free rows i, active columns
        j (sum_j w_ij R_j e_ij)."""
        n, nf = self.n, self.num_free
        nc = n - nf
        cf = np.zeros(n, dtype=bool)
        cf[dst[(src < nf) & (dst >= nf)]] = True
        act = np.concatenate([np.arange(nf), np.flatnonzero(cf)])
        inact = np.flatnonzero(~cf[nf:]) + nf
        nr = len(act)
        pos = np.full(n, -1, dtype=np.int64)
        pos[act] = np.arange(nr)
        self._act, self._inact, self._nr = act, inact, nr
        we = w2[:, None] * e

        def csr(rows, cols, vals, nrow):
            o = np.lexsort((cols, rows))
            ptr = np.zeros(nrow + 1, dtype=np.int64)
            np.cumsum(np.bincount(rows, minlength=nrow), out=ptr[1:])
            return ptr, np.ascontiguousarray(cols[o], dtype=np.int64), np.ascontiguousarray(vals[o])

        ps = pos[src]
        sel = (ps >= 0) & (dst < nf)
        ptr, col, val = csr(ps[sel], dst[sel], np.column_stack([we[sel], w2[sel]]), nr)
        # + the free-free weights and the degrees: L_ff x from the same loop.
        self._mrows = (ptr, col, np.ascontiguousarray(val[:, :3]), np.ascontiguousarray(val[:, 3]),
                       np.bincount(src, w2, minlength=n)[:nf].copy())
        sel = src < nf
        self._hrows = csr(src[sel], pos[dst[sel]], we[sel], nf)
        lu = spla.splu(self._L_ff.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                       options=dict(SymmetricMode=True))
        Lo = sp.tril(lu.L, -1, format="csc")
        d = lu.U.diagonal()
        if np.any(~(d > 0)):
            raise ValueError("free-node Laplacian is not positive definite")
        Up = sp.triu(lu.U, 1, format="csc")
        Lo.sort_indices()
        Up.sort_indices()
        i64 = np.int64
        self._lu = (lu.perm_r.astype(i64), lu.perm_c.astype(i64),
                    Lo.indptr.astype(i64), Lo.indices.astype(i64), Lo.data.astype(float),
                    Up.indptr.astype(i64), Up.indices.astype(i64), Up.data.astype(float), 1.0 / d)
        # M_i (active i) = M0_i + u_i c_i^T - sum_j w_ij u_j e_ij^T; the sum over
        # constrained j is formed once per solve (Kvc, Kvi: rows b * nrow + i).
        def stack_rows(rows, cols, wv, ev, nrow, ncol):
            return sp.csr_matrix(
                (np.concatenate([wv * ev[:, b] for b in range(3)]),
                 (np.concatenate([rows + b * nrow for b in range(3)]), np.tile(cols, 3))),
                shape=(3 * nrow, ncol))

        sel = (ps >= 0) & (dst >= nf)
        self._Kvc = stack_rows(ps[sel], dst[sel] - nf, w2[sel], e[sel], nr, nc)
        sel = ps < 0
        self._Kvi = stack_rows(np.searchsorted(inact, src[sel]), dst[sel] - nf, w2[sel], e[sel],
                               len(inact), nc)
        self._M0r = np.ascontiguousarray(self._M0[:, :, act])          # (3, 3, nr, 1)
        self._cr = np.ascontiguousarray(self._c[act])                    # (nr, 3)
        self._cf = np.ascontiguousarray(self._c[:nf])                    # (nf, 3)

    # ---- pieces of the plain iteration. Displacements are node-major U (n, A, 3)
    # (for the sparse products); rotations and M are component-first
    # (3, 3, n, A) so that the per-node 3x3 algebra runs on contiguous arrays.

    def _local_M(self, U: np.ndarray) -> np.ndarray:
        """M_i = sum_j w_ij e'_ij e_ij^T for displacements U (n, A, 3) -> (3, 3, n, A)."""
        n, A, _ = U.shape
        Kv = self._PlainOperators()[0]
        KU = (Kv @ U.reshape(n, 3 * A)).reshape(3, n, A, 3)          # [b, i, a, k]
        M = U.transpose(2, 0, 1)[:, None] * self._cT[None, :, :, None]
        M += self._M0
        M -= KU.transpose(3, 0, 1, 2)
        return M

    def _energy(self, U: np.ndarray, R: np.ndarray, M: np.ndarray) -> np.ndarray:
        n, A, _ = U.shape
        LU = (self.L @ U.reshape(n, 3 * A)).reshape(n, A, 3)
        quad = (4.0 * np.einsum("nak,nk->a", U, self._PlainOperators()[2])
                + 2.0 * np.einsum("nak,nak->a", U, LU))
        tr = np.einsum("kbna,kbna->a", R, M)
        return np.maximum(2.0 * self._e2 + quad - 2.0 * tr, 0.0)

    def _global(self, R: np.ndarray, U_c: np.ndarray) -> np.ndarray:
        """Free displacements (nf, A, 3) for rotations R (3, 3, n, A) and
        constrained displacements U_c (n_c, A, 3)."""
        n, A = R.shape[2:]
        nf = self.num_free
        Kh = self._PlainOperators()[1]
        Rstack = R.transpose(1, 2, 3, 0).reshape(3 * n, 3 * A)       # [b*n + j, a*3 + k]
        sRe = (Kh @ Rstack).reshape(n, A, 3)                          # sum_j w R_j e_ij
        Rc = np.einsum("kbia,bi->iak", R[:, :, :nf], self._cT[:, :nf])
        rhs = 0.5 * (Rc + sRe[:nf]) - self._c[:nf, None, :]
        rhs -= (self.L_fc @ U_c.reshape(len(U_c), 3 * A)).reshape(nf, A, 3)
        return np.asarray(self._solve(rhs.reshape(nf, 3 * A))).reshape(nf, A, 3)

    # ---- accelerated solver (same energy, same fixed point).

    def SolveAccelerated(self, constrained_displacements: np.ndarray, max_iterations: int = 300,
                         relative_tolerance: float = 1e-5, history: int = 8,
                         armijo: float = 1e-4, max_backtracks: int = 3,
                         warm_start: bool = True) -> ArapResult:
        """As ``SolvePlain`` (same energy, constraints, start and stopping
        rule) by L-BFGS on the free displacements (see the module notes),
        compiled (``arap_kernels.SolveTasks``): ``history`` (s, y) pairs,
        Armijo constant ``armijo``, up to ``max_backtracks`` step halvings.
        ``warm_start``: actions whose constrained displacements are a
        multiple s > 1 of another action's (the same pull, longer) start
        from s times that action's solution (displacements, and its
        rotations as the start of the per-node Newton iterations) instead
        of the Laplacian solve."""
        dU_c = np.asarray(constrained_displacements, dtype=float)
        A = dU_c.shape[0]
        n, nf, nr = self.n, self.num_free, self._nr
        nc = n - nf
        if dU_c.shape != (A, nc, 3):
            raise ValueError(f"constrained_displacements must be ({A}, {nc}, 3)")
        U_c = np.ascontiguousarray(dU_c.transpose(1, 0, 2))              # (nc, A, 3)
        Ucf = U_c.reshape(nc, 3 * A)
        act, inact = self._act, self._inact
        # Per-action constants.
        Mconst = self._M0r - (self._Kvc @ Ucf).reshape(3, nr, A, 3).transpose(3, 0, 1, 2)
        Mconst[:, :, nf:] += (U_c[act[nf:] - nf].transpose(2, 0, 1)[:, None]
                              * self._cr[nf:].T[None, :, :, None])
        z = (self.L_fc @ Ucf).reshape(nf, A, 3)
        rc = -self._cf[:, None, :] - z
        lin = 4.0 * (self._cf[:, None, :] + z)
        Lcc = (self._L_cc @ Ucf).reshape(nc, A, 3)
        # E = sum_i (S_i + s_i - 2 tr(R_i^T M_i)), S_i = sum_j w |e'_ij|^2, s_i = sum_j w |e_ij|^2:
        # sum_i S_i = e2 + 4 u.c + 2 u'Lu, sum_i s_i = e2; the inactive traces are constant.
        Econst = (2.0 * self._e2 + 4.0 * np.einsum("nak,nk->a", U_c, self._c[nf:])
                  + 2.0 * np.einsum("nak,nak->a", U_c, Lcc))
        R_out = np.zeros((A, n, 3, 3))
        ni = len(inact)
        pit = self.polar_iterations
        ptol = (1e-8, 1e-6, 1e-5)                 # PolarRotationQuaternion's tolerances
        if ni:
            Mi = (self._M0[:, :, inact]
                  + U_c[inact - nf].transpose(2, 0, 1)[:, None] * self._cT[None, :, inact, None]
                  - (self._Kvi @ Ucf).reshape(3, ni, A, 3).transpose(3, 0, 1, 2))
            Mi = np.ascontiguousarray(Mi.transpose(3, 2, 0, 1)).reshape(A * ni, 3, 3)
            qi = np.zeros((A * ni, 4))
            qi[:, 0] = 1.0
            Ri = K.PolarRotations(Mi, qi, K.LANES, pit, *ptol)
            Econst -= 2.0 * np.einsum("nab,nab->n", Ri, Mi).reshape(A, ni).sum(axis=1)
            R_out[:, inact] = Ri.reshape(A, ni, 3, 3)
        pred, ratio, _ = (_DistanceChains(dU_c) if warm_start
                          else (np.full(A, -1), np.ones(A), None))
        # Longest chains of warm starts first.
        height = np.ones(A, dtype=np.int64)
        for a in np.argsort(-np.linalg.norm(dU_c.reshape(A, -1), axis=1), kind="stable"):
            if pred[a] >= 0:
                height[pred[a]] = max(height[pred[a]], height[a] + 1)
        order = np.argsort(-height, kind="stable").astype(np.int64)
        c3 = lambda v: np.ascontiguousarray(v.transpose(1, 0, 2))      # (nf, A, 3) -> (A, nf, 3)
        Mc_t = np.ascontiguousarray(Mconst.transpose(3, 2, 0, 1))       # (A, nr, 3, 3)
        X = np.empty((A, nf, 3))
        Q = np.empty((A, nr, 4))
        Ra = np.empty((A, nr, 3, 3))
        energy = np.full(A, np.inf)
        iters = np.zeros(A, dtype=np.int64)
        converged = np.zeros(A, dtype=bool)
        floor = 1e-14 * max(self._e2, 1e-30)
        if A:
            K.SolveTasks(K.LANES, nf, self._cr, *self._mrows, *self._hrows, *self._lu,
                         Mc_t, c3(rc), c3(lin), c3(-z), Econst, pred.astype(np.int64),
                         ratio.astype(float), order, int(max_iterations), float(relative_tolerance),
                         float(floor), int(history), float(armijo), int(max_backtracks),
                         pit, *ptol, X, Q, Ra, energy, iters, converged)
        R_out[:, act] = Ra
        U_out = np.empty((A, n, 3))
        U_out[:, :nf] = X
        U_out[:, nf:] = dU_c
        return ArapResult(displacements=U_out, positions_W=self.rest_W[None] + U_out,
                          rotations=R_out, energy=energy, iterations=iters, converged=converged)

    def Solve(self, constrained_displacements: np.ndarray, max_iterations: int = 300,
              relative_tolerance: float = 1e-5, method: str = "lbfgs") -> ArapResult:
        """Minimises E for every action a given the displacements of the
        constrained nodes, ``constrained_displacements`` (A, n - num_free, 3)
        m. Starts from R = I (the first global step is the Laplacian solve);
        per action, stops when the relative energy decrease of one iteration
        drops below ``relative_tolerance`` (or the energy is at round-off
        level). ``method``: "lbfgs" (default, ``SolveAccelerated``) or
        "plain" (textbook global-local iterations, ``SolvePlain``)."""
        solve = dict(lbfgs=self.SolveAccelerated, plain=self.SolvePlain).get(method)
        if solve is None:
            raise ValueError(f"unknown ARAP method '{method}'")
        with SingleThreadBlas():
            return solve(constrained_displacements, max_iterations, relative_tolerance)

    def SolvePlain(self, constrained_displacements: np.ndarray, max_iterations: int = 300,
                   relative_tolerance: float = 1e-5) -> ArapResult:
        """Reference solver: alternate the local step (optimal rotations) and
        the global step (linear solve) until the relative energy decrease of
        one iteration drops below ``relative_tolerance``."""
        dU_c = np.asarray(constrained_displacements, dtype=float)
        A = dU_c.shape[0]
        n, nf = self.n, self.num_free
        if dU_c.shape != (A, n - nf, 3):
            raise ValueError(f"constrained_displacements must be ({A}, {n - nf}, 3)")
        U_c = np.ascontiguousarray(dU_c.transpose(1, 0, 2))          # (nc, A, 3)
        U = np.empty((n, A, 3))
        U[nf:] = U_c
        R = np.zeros((3, 3, n, A))
        R[0, 0] = R[1, 1] = R[2, 2] = 1.0
        q = np.zeros((4, n, A))
        q[0] = 1.0
        U[:nf] = self._global(R, U_c)
        energy = np.full(A, np.inf)
        iters = np.zeros(A, dtype=np.int64)
        converged = np.zeros(A, dtype=bool)
        floor = 1e-14 * max(self._e2, 1e-30)
        act = np.arange(A)
        for it in range(1, max_iterations + 1):
            Ua = U[:, act]
            M = self._local_M(Ua)
            Ra, qa = PolarRotationQuaternion(M, q[:, :, act], self.polar_iterations)
            Ea = self._energy(Ua, Ra, M)
            R[:, :, :, act], q[:, :, act] = Ra, qa
            prev = energy[act]
            done = (Ea <= floor) | (np.isfinite(prev)
                                   & (prev - Ea <= relative_tolerance * np.maximum(prev, floor)))
            energy[act] = Ea
            iters[act] = it
            converged[act[done]] = True
            if done.all():
                break
            keep = ~done
            act = act[keep]
            U[:nf, act] = self._global(R[:, :, :, act], U_c[:, act])
        U_out = U.transpose(1, 0, 2).copy()
        return ArapResult(displacements=U_out, positions_W=self.rest_W[None] + U_out,
                          rotations=R.transpose(3, 2, 0, 1).copy(), energy=energy,
                          iterations=iters, converged=converged)
