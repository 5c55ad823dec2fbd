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
warm-started quaternion iterations (Mueller et al. 2016), vectorised over
all nodes and actions; the result is always a proper rotation, so the
reflection case is handled by construction (same answer as the SVD with
the sign fix, see ``PolarRotationSvd``).
"""
from __future__ import annotations

import dataclasses as dc

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla


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


def PolarRotationQuaternion(M: np.ndarray, q: np.ndarray, max_iterations: int = 4,
                            tolerance: float = 1e-8, fallback_tolerance: float = 1e-3
                            ) -> tuple[np.ndarray, np.ndarray]:
    """Rotation maximising tr(R^T M) for every M (3, 3, ...) (component-first
    layout): up to ``max_iterations`` Mueller et al. (2016) steps from the
    unit quaternions ``q`` (4, ...) (warm start), then the SVD with the
    reflection fix for entries whose last step still exceeded
    ``fallback_tolerance`` rad. Returns (R (3, 3, ...), q)."""
    q = q.copy()
    R = QuaternionToMatrix(q)
    for it in range(max_iterations + 1):
        # omega = sum_c R[:, c] x M[:, c] / |sum_c R[:, c] . M[:, c]|
        ox = (R[1] * M[2] - R[2] * M[1]).sum(axis=0)
        oy = (R[2] * M[0] - R[0] * M[2]).sum(axis=0)
        oz = (R[0] * M[1] - R[1] * M[0]).sum(axis=0)
        dot = np.abs((R * M).sum(axis=(0, 1))) + 1e-300
        ox /= dot
        oy /= dot
        oz /= dot
        ang = np.sqrt(ox * ox + oy * oy + oz * oz)
        if not np.any(ang > tolerance):
            break
        if it == max_iterations:
            bad = ang > fallback_tolerance
            if np.any(bad):
                Mb = np.moveaxis(M[:, :, bad], -1, 0)
                Rb = np.moveaxis(PolarRotationSvd(Mb), 0, -1)
                R[:, :, bad] = Rb
                q[:, bad] = MatrixToQuaternion(Rb)
            break
        half = 0.5 * ang
        s = np.sinc(half / np.pi) * 0.5          # sin(ang/2) / ang
        dw, dx, dy, dz = np.cos(half), ox * s, oy * s, oz * s
        w, x, y, z = q
        q = np.stack([dw * w - dx * x - dy * y - dz * z,
                      dw * x + dx * w + dy * z - dz * y,
                      dw * y - dx * z + dy * w + dz * x,
                      dw * z + dx * y - dy * x + dz * w])
        q /= np.sqrt((q * q).sum(axis=0))
        R = QuaternionToMatrix(q)
    return R, q


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


class ArapProblem:
    """ARAP on a fixed graph: ``rest_W`` (n, 3) with the first ``num_free``
    nodes free, undirected ``edges`` (m, 2) with ``weights`` (m,). The
    Laplacian of the free nodes is factorised once here (``factorization``:
    "splu" sparse LU, "cholesky" dense Cholesky, "inverse" dense inverse)."""

    def __init__(self, rest_W: np.ndarray, edges: np.ndarray, weights: np.ndarray,
                 num_free: int, factorization: str = "inverse", polar_iterations: int = 4):
        rest = np.asarray(rest_W, dtype=float)
        n = len(rest)
        nf = int(num_free)
        if nf <= 0 or nf >= n:
            raise ValueError(f"need free and constrained nodes, got {nf} free of {n}")
        edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
        w = np.asarray(weights, dtype=float)
        src = np.concatenate([edges[:, 0], edges[:, 1]])
        dst = np.concatenate([edges[:, 1], edges[:, 0]])
        w2 = np.concatenate([w, w])
        e = rest[src] - rest[dst]                                    # (2m, 3)
        self.rest_W, self.n, self.num_free = rest, n, nf
        self.polar_iterations = int(polar_iterations)
        self.edges, self.weights = edges, w
        W = sp.csr_matrix((w2, (src, dst)), shape=(n, n))
        deg = np.asarray(W.sum(axis=1)).ravel()
        if np.any(deg[:nf] == 0):
            raise ValueError("free node without edges")
        L = (sp.diags(deg) - W).tocsr()
        self.L = L
        L_ff = L[:nf, :nf].tocsc()
        self.L_fc = L[:nf, nf:].tocsr()
        self.factorization = factorization
        if factorization == "splu":
            self._lu = spla.splu(L_ff, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                                 options=dict(SymmetricMode=True))
            self._solve = self._lu.solve
        elif factorization == "cholesky":
            cf = sla.cho_factor(L_ff.toarray(), lower=False, check_finite=False)
            self._solve = lambda b: sla.cho_solve(cf, b, check_finite=False)
        elif factorization == "inverse":
            # Dense inverse from the Cholesky factor (LAPACK potrf + potri).
            c, info = sla.lapack.dpotrf(L_ff.toarray(), lower=False)
            inv, info2 = sla.lapack.dpotri(c, lower=False)
            if info or info2:
                raise ValueError("free-node Laplacian is not positive definite")
            inv = np.triu(inv) + np.triu(inv, 1).T
            self._solve = lambda b: inv @ b
        else:
            raise ValueError(f"unknown factorization '{factorization}'")
        # K_b[i, j] = w_ij e_ij[b]; Kv = [K_0; K_1; K_2] (3n x n), Kh = [K_0 K_1 K_2].
        self._Kv = sp.csr_matrix(
            (np.concatenate([w2 * e[:, b] for b in range(3)]),
             (np.concatenate([src + b * n for b in range(3)]), np.tile(dst, 3))),
            shape=(3 * n, n))
        self._Kh = sp.csr_matrix(
            (np.concatenate([w2 * e[:, b] for b in range(3)]),
             (np.tile(src, 3), np.concatenate([dst + b * n for b in range(3)]))),
            shape=(n, 3 * n))
        self._c = np.stack([np.bincount(src, w2 * e[:, b], minlength=n)
                            for b in range(3)], axis=1)              # sum_j w e_ij
        self._cT = np.ascontiguousarray(self._c.T)
        self._M0 = np.stack([np.stack([np.bincount(src, w2 * e[:, k] * e[:, b], minlength=n)
                                       for b in range(3)]) for k in range(3)])[..., None]
        self._Lp = L @ rest
        self._e2 = float((w2 * (e * e).sum(1)).sum())

    # ---- pieces of the iteration. Displacements are node-major U (n, A, 3)
    # (for the sparse products); rotations and M are component-first
    # (3, 3, n, A) so that the per-node 3x3 algebra runs on contiguous arrays.

    def _local_M(self, U: np.ndarray) -> np.ndarray:
        """M_i = sum_j w_ij e'_ij e_ij^T for displacements U (n, A, 3) -> (3, 3, n, A)."""
        n, A, _ = U.shape
        KU = (self._Kv @ U.reshape(n, 3 * A)).reshape(3, n, A, 3)    # [b, i, a, k]
        M = U.transpose(2, 0, 1)[:, None] * self._cT[None, :, :, None]
        M += self._M0
        M -= KU.transpose(3, 0, 1, 2)
        return M

    def _energy(self, U: np.ndarray, R: np.ndarray, M: np.ndarray) -> np.ndarray:
        n, A, _ = U.shape
        LU = (self.L @ U.reshape(n, 3 * A)).reshape(n, A, 3)
        quad = 4.0 * np.einsum("nak,nk->a", U, self._Lp) + 2.0 * np.einsum("nak,nak->a", U, LU)
        tr = np.einsum("kbna,kbna->a", R, M)
        return np.maximum(2.0 * self._e2 + quad - 2.0 * tr, 0.0)

    def _global(self, R: np.ndarray, U_c: np.ndarray) -> np.ndarray:
        """Free displacements (nf, A, 3) for rotations R (3, 3, n, A) and
        constrained displacements U_c (n_c, A, 3)."""
        n, A = R.shape[2:]
        nf = self.num_free
        Rstack = R.transpose(1, 2, 3, 0).reshape(3 * n, 3 * A)       # [b*n + j, a*3 + k]
        sRe = (self._Kh @ Rstack).reshape(n, A, 3)                    # sum_j w R_j e_ij
        Rc = np.einsum("kbia,bi->iak", R[:, :, :nf], self._cT[:, :nf])
        rhs = 0.5 * (Rc + sRe[:nf]) - self._c[:nf, None, :]
        rhs -= (self.L_fc @ U_c.reshape(len(U_c), 3 * A)).reshape(nf, A, 3)
        return np.asarray(self._solve(rhs.reshape(nf, 3 * A))).reshape(nf, A, 3)

    def Solve(self, constrained_displacements: np.ndarray, max_iterations: int = 300,
              relative_tolerance: float = 1e-5) -> ArapResult:
        """Minimises E for every action a given the displacements of the
        constrained nodes, ``constrained_displacements`` (A, n - num_free, 3)
        m. Starts from R = I; per action, stops when the relative energy
        decrease of one iteration drops below ``relative_tolerance`` (or the
        energy is at round-off level)."""
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
