"""The convex CCP subproblem as conic data (Clarabel's form A z + s = b, s in K).

Assembled directly with numpy, vectorised over transitions and hazards, so
building it takes milliseconds instead of the tens of seconds CVXPY's
canonicalisation needed (numerics.md). The sparsity pattern and the cone list
depend only on (scenario, K); each CCP iteration changes numbers only: the
objective's linear term (gradient of log det Y at the current point) and the
linearised collision rows (u~, rho).

Cones used (scaled units, see model.py):
  PSD(d)     S_k >= 0
  PSD(2d)    Kalman relaxation (errata 7): [[W^-1 - Q_k, W^-1], [W^-1, Y_{k-1} + W^-1]] >= 0, k >= 2
  PSD(2d)+exp  log det Q_k epigraph: [[Q, Z], [Z^T, diag Z]] >= 0, Z lower triangular,
             u_i <= log Z_ii, so log det Q >= sum u_i
  PSD(d+1)   h1 of eq. doc: [[R, v^T], [v, Y]] >= 0 at both ends of a transition
  SOC(d+2)   the convexified h2: 1/2 ||sqrt(rho) v - x/sqrt(rho)||^2 <= w
  SOC(3), PSD(d+1)  target containment, final_cond with the corrected sign (errata 4)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .model import Layout, ProblemData

__all__ = ["SubproblemData", "ConicSubproblem"]

_SQ2 = np.sqrt(2.0)


def _tri_pos(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Upper-triangle entries of an n x n matrix in Clarabel's order (column
    major), with their svec scale (sqrt 2 off the diagonal)."""
    ii, jj = [], []
    for j in range(n):
        for i in range(j + 1):
            ii.append(i)
            jj.append(j)
    ii = np.array(ii)
    jj = np.array(jj)
    pos = np.arange(ii.size)
    scale = np.where(ii == jj, 1.0, _SQ2)
    return ii, jj, pos, scale


@dataclass
class SubproblemData:
    P: sp.csc_matrix
    q: np.ndarray
    A: sp.csc_matrix
    b: np.ndarray
    cones: list
    spec: list            # (kind, n, rows) per cone: "psd" (n x n), "soc" (n), "exp" (3)

    def slack_violations(self, z: np.ndarray) -> np.ndarray:
        """Per cone, how far s = b - A z is from the cone (0 when inside)."""
        s = self.b - self.A @ z
        out = np.zeros(len(self.spec))
        row = 0
        for i, (kind, n, m) in enumerate(self.spec):
            v = s[row:row + m]
            if kind == "psd":
                M = np.zeros((n, n))
                ii, jj, pos, scale = _tri_pos(n)
                M[ii, jj] = v / scale
                M[jj, ii] = v / scale
                out[i] = max(0.0, -np.linalg.eigvalsh(M)[0])
            elif kind == "nonneg":
                out[i] = max(0.0, -float(np.min(v)))
            elif kind == "soc":
                out[i] = max(0.0, np.linalg.norm(v[1:]) - v[0])
            else:  # exp: y e^(x/y) <= z
                out[i] = max(0.0, v[1] * np.exp(v[0] / v[1]) - v[2]) if v[1] > 0 else abs(v[1])
            row += m
        return out


class _Acc:
    """Collects (row, col, val) triplets of E and constants e with s = E z + e."""

    def __init__(self) -> None:
        self.r: list[np.ndarray] = []
        self.c: list[np.ndarray] = []
        self.v: list[np.ndarray] = []
        self.br: list[np.ndarray] = []
        self.bv: list[np.ndarray] = []
        self.cones: list = []
        self.spec: list = []
        self.m = 0

    def rows(self, B: int, n: int, cone) -> np.ndarray:
        base = self.m + n * np.arange(B)
        self.m += B * n
        self.cones.extend([cone] * B)
        name = type(cone).__name__
        kind = ("psd" if "PSD" in name else "soc" if "SecondOrder" in name
                else "nonneg" if "Nonneg" in name else "exp")
        dim = int(getattr(cone, "dim", 3)) if kind != "exp" else 3
        self.spec.extend([(kind, dim, n)] * B)
        return base

    def term(self, row, idx, coef) -> None:
        row, idx, coef = np.broadcast_arrays(np.asarray(row), np.asarray(idx), np.asarray(coef, float))
        keep = idx >= 0
        self.r.append(row[keep].ravel())
        self.c.append(idx[keep].ravel())
        self.v.append(coef[keep].ravel())

    def const(self, row, val) -> None:
        row, val = np.broadcast_arrays(np.asarray(row), np.asarray(val, float))
        self.br.append(row.ravel())
        self.bv.append(val.ravel())

    def finish(self, nvar: int) -> tuple[sp.csc_matrix, np.ndarray]:
        r = np.concatenate(self.r)
        c = np.concatenate(self.c)
        v = np.concatenate(self.v)
        E = sp.csc_matrix((v, (r, c)), shape=(self.m, nvar))
        e = np.zeros(self.m)
        np.add.at(e, np.concatenate(self.br), np.concatenate(self.bv))
        return -E, e


class ConicSubproblem:
    """Variable layout and conic data of the CCP subproblem for one model."""

    def __init__(self, data: ProblemData, chi2_margin: float = 1e-7):
        import clarabel

        self.D = data
        self.chi2 = data.chi2 * (1.0 + chi2_margin)
        self._clarabel = clarabel
        D = data
        K, J, F, d = D.K, D.J, D.F, D.d
        nt = d * (d + 1) // 2
        self.nt = nt
        n = 0

        def alloc(count: int) -> np.ndarray:
            nonlocal n
            out = np.arange(n, n + count)
            n += count
            return out

        # symmetric matrix variables: index map (K+1, d, d), -1 where constant
        ti, tj, _, _ = _tri_pos(d)

        def sym_map(ks: np.ndarray) -> np.ndarray:
            out = -np.ones((K + 1, d, d), dtype=int)
            for k in ks:
                idx = alloc(nt)
                out[k, ti, tj] = idx
                out[k, tj, ti] = idx
            return out

        self.ix = -np.ones((K + 1, d), dtype=int)
        self.ix[1:] = alloc(K * d).reshape(K, d)
        self.iQ = sym_map(np.arange(2, K + 1))
        self.iS = sym_map(np.arange(1, K + 1))
        lam = -np.ones((K, J, F), dtype=int)
        lam[:, D.face_mask] = alloc(K * int(D.face_mask.sum())).reshape(K, -1)
        self.ilam = lam
        self.iR1 = alloc(K * J).reshape(K, J)
        self.iR0 = -np.ones((K, J), dtype=int)
        if K > 1:
            self.iR0[1:] = alloc((K - 1) * J).reshape(K - 1, J)
        self.iC = alloc(D.At.shape[0])
        self.iZ = -np.ones((K + 1, d, d), dtype=int)      # lower triangular
        self.iu = -np.ones((K + 1, d), dtype=int)
        for k in range(2, K + 1):
            self.iZ[k][np.tril_indices(d)] = alloc(nt)
            self.iu[k] = alloc(d)
        self.nvar = n
        self._P = self._objective_quadratic()

    # --------------------------------------------------------------- pieces
    def _objective_quadratic(self) -> sp.csc_matrix:
        D = self.D
        K, d = D.K, D.d
        # sigma^2 sum_k ||x_k - x_{k-1}||^2 = 1/2 z^T P z + linear (x_0 terms)
        Dm = sp.diags([np.ones(K), -np.ones(K - 1)], [0, -1], shape=(K, K))
        H = 2 * D.sigma**2 * (Dm.T @ Dm)
        Hx = sp.kron(H, sp.eye(d))
        cols = self.ix[1:].ravel()
        Hc = Hx.tocoo()
        P = sp.csc_matrix((Hc.data, (cols[Hc.row], cols[Hc.col])), shape=(self.nvar, self.nvar))
        return sp.triu(P, format="csc")

    def _matrix_block(self, acc: _Acc, base: np.ndarray, n: int, entries) -> None:
        """PSD(n) rows: ``entries(i, j)`` yields (idx, coef) terms and a constant
        for the (i, j) entry (i <= j) of every cone of the batch."""
        ii, jj, pos, scale = _tri_pos(n)
        for i, j, p, s in zip(ii, jj, pos, scale):
            terms, const = entries(i, j)
            for idx, coef in terms:
                acc.term(base[:, None] + p if np.ndim(idx) == 2 else base + p, idx, s * np.asarray(coef))
            if const is not None:
                acc.const(base + p, s * np.asarray(const))

    def build(self, z: Layout, rho_start: np.ndarray, rho_end: np.ndarray, grad_logdet: np.ndarray,
              grad_start: tuple[np.ndarray, np.ndarray], grad_end: tuple[np.ndarray, np.ndarray]) -> SubproblemData:
        """Conic data linearised at ``z``; the mean variables are the steps
        delta_k = x_k - x~_k (see :meth:`extract`).

        rho_* (K, J) split weights of the collision constraints at the start
        and end of each transition; grad_logdet (K, d, d) = Y~_k^-1, the
        gradient of the concave objective part; grad_start / grad_end the
        gradients (d/dlam (K, J, F), d/dx (K, J, d)) of the bilinear
        collision term at both ends -- all from the CasADi model.
        """
        cl = self._clarabel
        D = self.D
        K, J, F, d = D.K, D.J, D.F, D.d
        acc = _Acc()
        Wi = np.linalg.inv(D.W)
        kk = np.arange(1, K + 1)

        # lam >= 0 (Lemma 1 / Theorem 1)
        lam_idx = self.ilam[self.ilam >= 0]
        base = acc.rows(1, lam_idx.size, cl.NonnegativeConeT(lam_idx.size))
        acc.term(base[0] + np.arange(lam_idx.size), lam_idx, 1.0)

        # S_k >= 0
        base = acc.rows(K, d * (d + 1) // 2, cl.PSDTriangleConeT(d))
        self._matrix_block(acc, base, d, lambda i, j: ([(self.iS[kk, i, j], 1.0)], None))

        if K > 1:
            k2 = np.arange(2, K + 1)
            n2 = 2 * d
            # Kalman relaxation (errata 7)
            base = acc.rows(K - 1, n2 * (n2 + 1) // 2, cl.PSDTriangleConeT(n2))
            Q1 = D.Q1

            def kalman(i, j):
                if j < d:            # top-left: W^-1 - Q_k
                    return [(self.iQ[k2, i, j], -1.0)], np.full(K - 1, Wi[i, j])
                if i < d:            # top-right: W^-1
                    return [], np.full(K - 1, Wi[i, j - d])
                a, c = i - d, j - d  # bottom-right: Q_{k-1} + S_{k-1} + W^-1
                const = np.full(K - 1, Wi[a, c])
                const[0] += Q1[a, c]
                return [(self.iQ[k2 - 1, a, c], 1.0), (self.iS[k2 - 1, a, c], 1.0)], const

            self._matrix_block(acc, base, n2, kalman)
            # log det Q_k epigraph
            base = acc.rows(K - 1, n2 * (n2 + 1) // 2, cl.PSDTriangleConeT(n2))

            def logdet_blk(i, j):
                if j < d:
                    return [(self.iQ[k2, i, j], 1.0)], None
                if i < d:            # Z_{i, j-d}, lower triangular
                    return [(self.iZ[k2, i, j - d], 1.0)], None
                if i == j:
                    return [(self.iZ[k2, i - d, i - d], 1.0)], None
                return [], None

            self._matrix_block(acc, base, n2, logdet_blk)
            base = acc.rows((K - 1) * d, 3, cl.ExponentialConeT())
            iu = self.iu[k2].ravel()
            iz = np.stack([self.iZ[k2, i, i] for i in range(d)], axis=1).ravel()
            acc.term(base, iu, 1.0)
            acc.const(base + 1, 1.0)
            acc.term(base + 2, iz, 1.0)

        # collision constraints (transition k, hazard j), Theorem 1
        v_t = np.einsum("jfd,kjf->kjd", D.A, z.lam)      # v~ = A^T lam~
        self._collision_end(acc, grad_end, v_t, rho_end)
        if K > 1:
            self._collision_start(acc, grad_start, v_t, rho_start)
        self._collision_first(acc)
        self._target(acc, z)

        Amat, bvec = acc.finish(self.nvar)
        q = self._linear_objective(grad_logdet, z)
        return SubproblemData(self._P, q, Amat, bvec, acc.cones, acc.spec)

    def _h1(self, acc: _Acc, ks: np.ndarray, iR: np.ndarray, Ymaps, Yconst: np.ndarray) -> None:
        """[[R, v^T], [v, Y_k]] >= 0 for transitions ks (1-based) x all hazards."""
        cl = self._clarabel
        D = self.D
        J, F, d = D.J, D.F, D.d
        B = ks.size * J
        n = d + 1
        base = acc.rows(B, n * (n + 1) // 2, cl.PSDTriangleConeT(n)).reshape(ks.size, J)
        lam = self.ilam[ks - 1]                                         # (nk, J, F)
        ii, jj, pos, scale = _tri_pos(n)
        for i, j, p, s in zip(ii, jj, pos, scale):
            rows = base + p
            if i == 0 and j == 0:
                acc.term(rows, iR, s)
            elif i == 0:
                # v_{j-1} = sum_f A_{j f, j-1} lam_f
                coef = np.broadcast_to(D.A[None, :, :, j - 1], lam.shape)
                acc.term(rows[..., None], lam, s * coef)
            else:
                for imap in Ymaps:
                    acc.term(rows, imap[ks, i - 1, j - 1][:, None], s)
                acc.const(rows, s * Yconst[:, i - 1, j - 1][:, None])

    def _h2(self, acc: _Acc, ks: np.ndarray, iR: np.ndarray, idk: np.ndarray, g_lam: np.ndarray,
            g_x: np.ndarray, v_t: np.ndarray, rho: np.ndarray) -> None:
        """Convexified h2 in step variables delta = x - x~ (model.py, DC split):

            1/2 ||sqrt(rho) (v - v~) - delta / sqrt(rho)||^2
                <= -R - chi2 + lam^T g_lam + delta^T g_x

        i.e. R + chi2 - 2 lam^T (A x - b) <= 0 with the bilinear term replaced
        by its convex majorant; g_lam = 2 (A x~ - b) and g_x = 2 v~ are the
        gradient of h = 2 lam^T (A x - b) at the current point (CasADi model),
        and h~ - grad h~ . (lam~, 0) = 0 because h is bilinear."""
        cl = self._clarabel
        D = self.D
        J, d = D.J, D.d
        nk = ks.size
        base = acc.rows(nk * J, d + 2, cl.SecondOrderConeT(d + 2)).reshape(nk, J)
        lam = self.ilam[ks - 1]                                          # (nk, J, F)
        sr = np.sqrt(rho)                                                # (nk, J)
        for row, off in ((base, 1.0), (base + d + 1, -1.0)):
            acc.term(row, iR, -1 / _SQ2)
            acc.term(row[..., None], lam, g_lam / _SQ2)
            acc.term(row[..., None], idk[:, None, :], g_x / _SQ2)
            acc.const(row, (-self.chi2 + off) / _SQ2)
        for i in range(d):
            row = base + 1 + i
            acc.term(row[..., None], lam, sr[..., None] * D.A[None, :, :, i])
            acc.term(row, idk[:, None, i], -1 / sr)
            acc.const(row, -sr * v_t[..., i])

    def _collision_end(self, acc, grads, v_t: np.ndarray, rho: np.ndarray) -> None:
        D = self.D
        K = D.K
        ks = np.arange(1, K + 1)
        Yconst = np.zeros((K, D.d, D.d))
        Yconst[0] = D.Q1                                   # Q_1 fixed
        self._h1(acc, ks, self.iR1, [self.iQ], Yconst)
        self._h2(acc, ks, self.iR1, self.ix[ks], *grads, v_t, rho)

    def _collision_start(self, acc, grads, v_t: np.ndarray, rho: np.ndarray) -> None:
        D = self.D
        K = D.K
        ks = np.arange(2, K + 1)
        Yconst = np.zeros((K - 1, D.d, D.d))
        Yconst[0] = D.Q1                                   # Y_1 = Q_1 + S_1
        # Y_{k-1}: shift the maps by one step
        shiftQ = np.concatenate([self.iQ[:1], self.iQ[:-1]])
        shiftS = np.concatenate([self.iS[:1], self.iS[:-1]])
        self._h1(acc, ks, self.iR0[1:], [shiftQ, shiftS], Yconst)
        self._h2(acc, ks, self.iR0[1:], self.ix[ks - 1], grads[0][1:], grads[1][1:], v_t[1:], rho[1:])

    def _collision_first(self, acc) -> None:
        """k = 1, start end (errata 8): ||P0^1/2 v||^2 <= 2 lam^T (A x0 - b) - chi2."""
        cl = self._clarabel
        D = self.D
        J, F, d = D.J, D.F, D.d
        base = acc.rows(J, d + 2, cl.SecondOrderConeT(d + 2))
        w, V = np.linalg.eigh(D.P0)
        Lh = V * np.sqrt(np.maximum(w, 0.0))                   # P0 = Lh Lh^T
        c0 = np.einsum("jfd,d->jf", D.A, D.x0) - D.b            # A x0 - b
        l1 = self.ilam[0]                                      # (J, F)
        for row, off in ((base, 1.0), (base + d + 1, -1.0)):
            acc.term(row[:, None], l1, c0 / _SQ2)
            acc.const(row, (-self.chi2 / 2 + off) / _SQ2)
        for i in range(d):
            # z_i = (Lh^T v)_i = sum_f lam_f (Lh^T a_f)_i
            coef = np.einsum("d,jfd->jf", Lh[:, i], D.A)
            acc.term(base[:, None] + 1 + i, l1, coef)

    def _target(self, acc, z: Layout) -> None:
        cl = self._clarabel
        D = self.D
        d, K = D.d, D.K
        N = D.At.shape[0]
        gamma = 1.0 / np.sqrt(self.chi2)
        # (b_n - a_n^T x_K) * gamma C_n >= 1  as SOC(3)
        base = acc.rows(N, 3, cl.SecondOrderConeT(3))
        xK = self.ix[K]
        for row, sgn in ((base, 1.0), (base + 2, -1.0)):
            acc.term(row[:, None], xK[None, :], -D.At / _SQ2)
            acc.const(row, (D.bt - D.At @ z.x[K]) / _SQ2)
            acc.term(row, self.iC, sgn * gamma / _SQ2)
        acc.const(base + 1, _SQ2)
        # [[1, C a^T], [C a, Y_K]] >= 0
        n = d + 1
        base = acc.rows(N, n * (n + 1) // 2, cl.PSDTriangleConeT(n))
        ii, jj, pos, scale = _tri_pos(n)
        Yc = D.Q1 if K == 1 else np.zeros((d, d))
        for i, j, p, s in zip(ii, jj, pos, scale):
            row = base + p
            if i == 0 and j == 0:
                acc.const(row, 1.0)
            elif i == 0:
                acc.term(row, self.iC, s * D.At[:, j - 1])
            else:
                acc.term(row, self.iQ[K, i - 1, j - 1], s)
                acc.term(row, self.iS[K, i - 1, j - 1], s)
                acc.const(row, np.full(N, s * Yc[i - 1, j - 1]))

    def _linear_objective(self, G: np.ndarray, z: Layout) -> np.ndarray:
        """q: alpha/2 tr(G_k Y_k) - alpha/2 sum u_k + the control term's
        gradient at x~ (the control term is quadratic in delta)."""
        D = self.D
        K, d = D.K, D.d
        q = np.zeros(self.nvar)
        ti, tj, _, _ = _tri_pos(d)
        w = np.where(ti == tj, 1.0, 2.0)                     # symmetric entries stored once
        for imap in (self.iQ, self.iS):
            idx = imap[1:, ti, tj]                            # (K, nt)
            coef = 0.5 * D.alpha * G[:, ti, tj] * w
            keep = idx >= 0
            np.add.at(q, idx[keep], coef[keep])
        if K > 1:
            q[self.iu[2:].ravel()] -= 0.5 * D.alpha
        dx = np.diff(z.x, axis=0)                            # x~_k - x~_{k-1}, k = 1..K
        gx = 2 * D.sigma**2 * (dx - np.vstack([dx[1:], np.zeros((1, d))]))
        np.add.at(q, self.ix[1:].ravel(), gx.ravel())
        return q

    def point_vector(self, z: Layout) -> np.ndarray:
        """The variable vector of ``z`` itself (delta = 0), with the auxiliary
        variables at their tightest values: R = v^T Y^-1 v, C_n = 1 / sqrt(a^T Y_K^-1 a),
        Z = L diag(L) and u = log diag(Z) for Q = L L^T. CCP's current point
        must be feasible for the subproblem built at it (tests check this)."""
        D = self.D
        K, d = D.K, D.d
        out = np.zeros(self.nvar)
        for imap, M in ((self.iQ, z.Q), (self.iS, z.S)):
            keep = imap >= 0
            out[imap[keep]] = M[keep]
        keep = self.ilam >= 0
        out[self.ilam[keep]] = z.lam[keep]
        v = np.einsum("jfd,kjf->kjd", D.A, z.lam)
        Y = z.Y
        out[self.iR1] = np.einsum("kjd,kjd->kj", v, np.linalg.solve(z.Q[1:, None], v[..., None])[..., 0])
        if K > 1:
            vv = v[1:]
            out[self.iR0[1:]] = np.einsum("kjd,kjd->kj", vv, np.linalg.solve(Y[1:-1, None], vv[..., None])[..., 0])
        aYa = np.einsum("nd,nd->n", D.At, np.linalg.solve(Y[K], D.At.T).T)
        out[self.iC] = 1.0 / np.sqrt(aYa)
        for k in range(2, K + 1):
            L = np.linalg.cholesky(z.Q[k])
            Z = L * np.diag(L)[None, :]
            rows, cols = np.tril_indices(d)
            out[self.iZ[k][rows, cols]] = Z[rows, cols]
            out[self.iu[k]] = np.log(np.diag(Z))
        return out

    # ------------------------------------------------------------ extract
    def extract(self, sol: np.ndarray, z: Layout) -> Layout:
        """The new point from a solution vector (means = x~ + delta)."""
        D = self.D
        K, d = D.K, D.d
        x = z.x.copy()
        x[1:] += sol[self.ix[1:]]
        Q = np.zeros((K + 1, d, d))
        Q[1] = D.Q1
        if K > 1:
            Q[2:] = sol[self.iQ[2:]]
        S = np.zeros((K + 1, d, d))
        S[1:] = sol[self.iS[1:]]
        # the solver keeps S >= 0 only to its tolerance; clipping the tiny
        # negative eigenvalues adds sensing, which can only shrink ellipses
        w, V = np.linalg.eigh(S[1:])
        S[1:] = (V * np.maximum(w, 0.0)[:, None, :]) @ np.swapaxes(V, -1, -2)
        lam = np.where(self.ilam >= 0, sol[np.maximum(self.ilam, 0)], 0.0)
        return Layout(x, Q, S, np.maximum(lam, 0.0))
