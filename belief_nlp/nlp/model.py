"""The minimum-sensing path problem as a CasADi model (paper eqs. main_info ->
prob_2 -> main_doc, with the errata), the single source of truth for the
objective, the constraints and the difference-of-convex split.

Units. Internally every length is divided by sigma = sqrt(max eig W) (see
numerics.md: in metres W ~ 2e-4 and P0^-1 ~ 1e9 break both solvers). So
x' = x / sigma, P' = P / sigma^2, W' = W / sigma^2 (~ I), Q' = sigma^2 Q, and a
lambda of Lemma 1 scales as lambda' = sigma * lambda. The cost
sum ||dx||^2 + alpha/2 sum (log det Y_k - log det Q_k) becomes
sigma^2 sum ||dx'||^2 + the (scale-free) information term.

Variables (scaled), k = 1..K:
  x_k           means (x_0 fixed)
  Q_k           prior information (P_{k-1} + W)^-1, relaxed to
                Q_k^-1 >= Y_{k-1}^-1 + W (prob_2; tight at the optimum, Lemma 2).
                Q_1 = (P0 + W)^-1 is fixed (errata 8: no P0^-1 anywhere).
  S_k >= 0      sensing information; Y_k = Q_k + S_k posterior information
  lam_{k,j}>=0  one common certificate per transition k and hazard j (Theorem 1)

Constraints, for every transition k and hazard j (obstacles, then domain walls
as half-spaces) with v = A_j^T lam, c(x) = A_j x - b_j:
  start end  v^T Y_{k-1}^-1 v - 2 lam^T c(x_{k-1}) + chi2 <= 0   (k >= 2)
             v^T P0 v         - 2 lam^T c(x_0)     + chi2 <= 0   (k = 1, errata 8)
  final end  v^T Q_k^-1 v     - 2 lam^T c(x_k)     + chi2 <= 0   (tran_col_2, errata 5)
and target containment of the final posterior (final_cond with errata 4):
  b_n - a_n^T x_K - chi sqrt(a_n^T Y_K^-1 a_n) >= 0.

DC split. The objective's concave part is alpha/2 log det Y_k (linearised
by its gradient Y~_k^-1). In each collision constraint the bilinear term
h(lam, x) = 2 lam^T (A x - b) is expanded exactly around the current point,
h = h~ + grad h~ . (dlam, dx) + 2 dv^T dx (dv = A^T dlam), and the last,
indefinite part is split as convex minus convex,
  -2 dv^T dx = 1/2 ||sqrt(rho) dv - dx/sqrt(rho)||^2 - 1/2 ||sqrt(rho) dv + dx/sqrt(rho)||^2,
whose concave half linearises to 0 at the current point. The result is a
convex majorant tight at the current point (CCP's requirement), and any
rho > 0 is valid, so rho may change per iteration (we adapt it to the last
step). The paper's split (eq. doc) is the same idea with (A x - b, lam) in
place of (dx, dv), rho = 1, and not centred at the current point: it mixes
quantities of very different size, the fragility numerics.md reports.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np

from ..scenario import Scenario

__all__ = ["Layout", "ProblemData", "BeliefModel"]


@dataclass(frozen=True)
class ProblemData:
    """Scenario data in scaled units, hazards padded to a common face count."""

    sigma: float
    chi2: float
    alpha: float
    K: int
    d: int
    x0: np.ndarray            # (d,)
    P0: np.ndarray            # (d, d)
    W: np.ndarray             # (d, d)
    A: np.ndarray             # (J, F, d) hazard normals (padded rows zero)
    b: np.ndarray             # (J, F)
    face_mask: np.ndarray     # (J, F) bool
    hazard_names: tuple
    At: np.ndarray            # (N, d) target normals
    bt: np.ndarray            # (N,)

    @classmethod
    def from_scenario(cls, scenario: Scenario, K: int, alpha: float | None = None) -> "ProblemData":
        W = np.asarray(scenario.W, float)
        sigma = float(np.sqrt(np.max(np.linalg.eigvalsh(W))))
        hz = scenario.hazards
        F = max(h.n_faces for h in hz)
        J = len(hz)
        d = scenario.dim
        A = np.zeros((J, F, d))
        b = np.zeros((J, F))
        mask = np.zeros((J, F), bool)
        for j, h in enumerate(hz):
            A[j, : h.n_faces] = h.A
            b[j, : h.n_faces] = h.b / sigma
            mask[j, : h.n_faces] = True
        return cls(
            sigma=sigma, chi2=float(scenario.chi2),
            alpha=float(scenario.alpha if alpha is None else alpha), K=int(K), d=d,
            x0=scenario.x0 / sigma, P0=scenario.P0 / sigma**2, W=W / sigma**2,
            A=A, b=b, face_mask=mask, hazard_names=tuple(h.name for h in hz),
            At=scenario.target.A.copy(), bt=scenario.target.b / sigma,
        )

    @property
    def J(self) -> int:
        return int(self.A.shape[0])

    @property
    def F(self) -> int:
        return int(self.A.shape[1])

    @cached_property
    def Q1(self) -> np.ndarray:
        """Fixed prior information of step 1, (P0 + W)^-1 (errata 8)."""
        return np.linalg.inv(self.P0 + self.W)


@dataclass
class Layout:
    """A point of the model in scaled units (k = 0..K; index 0 holds constants)."""

    x: np.ndarray     # (K+1, d)
    Q: np.ndarray     # (K+1, d, d) prior information (Q[0] unused, Q[1] fixed)
    S: np.ndarray     # (K+1, d, d) sensing information (S[0] = 0)
    lam: np.ndarray   # (K, J, F) certificates of transitions 1..K (padded faces 0)

    @property
    def Y(self) -> np.ndarray:
        return self.Q + self.S

    def copy(self) -> "Layout":
        return Layout(self.x.copy(), self.Q.copy(), self.S.copy(), self.lam.copy())


def _sym(M: np.ndarray) -> np.ndarray:
    return 0.5 * (M + np.swapaxes(M, -1, -2))


class BeliefModel:
    """The CasADi model of the smoothing problem for one scenario and horizon.

    Builds its CasADi functions once (SX, then ``expand``ed); evaluate them
    through the methods below, which accept a :class:`Layout`.
    """

    def __init__(self, scenario: Scenario, K: int, alpha: float | None = None):
        self.scenario = scenario
        self.data = ProblemData.from_scenario(scenario, K, alpha)
        self._build()

    # ------------------------------------------------------------ casadi
    def _build(self) -> None:
        D = self.data
        d, F = D.d, D.F
        Y = ca.SX.sym("Y", d, d)
        Q = ca.SX.sym("Q", d, d)
        # objective pieces for one step: convex -alpha/2 logdet Q, concave alpha/2 logdet Y
        logdet_Y = ca.log(ca.det(Y))
        self.f_logdet_grad = ca.Function("logdet_grad", [Y], [logdet_Y, ca.gradient(logdet_Y, Y)],
                                         ["Y"], ["logdet", "grad"])
        # bilinear part of one collision end, h(lam, x) = 2 lam^T (A x - b), and
        # its gradient: the linear part of CCP's majorant (see module doc)
        x = ca.SX.sym("x", d)
        lam_h = ca.SX.sym("lam", F)
        A_h = ca.SX.sym("A", F, d)
        b_h = ca.SX.sym("b", F)
        h = 2 * ca.dot(lam_h, A_h @ x - b_h)
        self.f_bilinear = ca.Function("bilinear", [lam_h, x, A_h, b_h],
                                      [h, ca.gradient(h, lam_h), ca.gradient(h, x)],
                                      ["lam", "x", "A", "b"], ["value", "grad_lam", "grad_x"])
        # full collision margin of one end (Lemma 1 form):
        # -v^T Y^-1 v + 2 lam^T (A x - b) - chi2  (>= 0 is clear)
        lam = ca.SX.sym("lam", F)
        A = ca.SX.sym("A", F, d)
        bb = ca.SX.sym("b", F)
        vv = A.T @ lam
        margin = -ca.dot(vv, ca.solve(Y, vv)) + 2 * ca.dot(lam, A @ x - bb) - D.chi2
        self.f_end_margin = ca.Function("end_margin", [x, Y, lam, A, bb], [margin],
                                        ["x", "Yend", "lam", "A", "b"], ["margin"])
        P = ca.SX.sym("P", d, d)
        margin0 = -ca.dot(vv, P @ vv) + 2 * ca.dot(lam, A @ x - bb) - D.chi2
        self.f_start_margin_P = ca.Function("start_margin_P", [x, P, lam, A, bb], [margin0],
                                            ["x", "P", "lam", "A", "b"], ["margin"])
        # target containment of one face
        a = ca.SX.sym("a", d)
        bt = ca.SX.sym("bt")
        cont = bt - ca.dot(a, x) - ca.sqrt(D.chi2 * ca.dot(a, ca.solve(Y, a)))
        self.f_containment = ca.Function("containment", [x, Y, a, bt], [cont], ["x", "Y", "a", "b"], ["margin"])
        # Kalman relaxation residual, smallest eigenvalue of Q^-1 - Y_prev^-1 - W >= 0
        Yp = ca.SX.sym("Yp", d, d)
        kal = ca.inv(Q) - ca.inv(Yp) - D.W
        self.f_kalman = ca.Function("kalman_gap", [Q, Yp], [kal], ["Q", "Yprev"], ["gap"])

    # ------------------------------------------------------ evaluations
    def cost(self, z: Layout) -> tuple[float, float, float]:
        """(total, control, information) in SI units: sum ||dx||^2 (m^2) and nats."""
        D = self.data
        control = float(D.sigma**2 * np.sum(np.diff(z.x, axis=0) ** 2))
        Y = z.Y[1:]
        Qk = z.Q[1:]
        info = 0.5 * float(np.sum(np.linalg.slogdet(Y)[1] - np.linalg.slogdet(Qk)[1]))
        return control + D.alpha * info, control, info

    def logdet_gradients(self, z: Layout) -> np.ndarray:
        """d/dY log det Y_k for k = 1..K (= Y_k^-1), from the CasADi model, (K, d, d)."""
        f = self.f_logdet_grad.map(self.data.K)
        Yh = np.concatenate(list(z.Y[1:]), axis=1)           # d x (K d)
        g = np.asarray(f(Yh)[1])
        return _sym(np.stack(np.split(g, self.data.K, axis=1)))

    def bilinear_gradients(self, z: Layout, end: bool) -> tuple[np.ndarray, np.ndarray]:
        """Gradient of h(lam, x) = 2 lam^T (A x - b) at the current point for every
        transition k and hazard j, at the transition's end (x_k) or start
        (x_{k-1}); from the CasADi model. Returns (d/dlam (K, J, F), d/dx (K, J, d))."""
        D = self.data
        K, J, F, d = D.K, D.J, D.F, D.d
        n = K * J
        xs = z.x[1:] if end else z.x[:-1]
        f = self.f_bilinear.map(n)
        lam = z.lam.reshape(n, F).T
        A = np.concatenate([D.A] * K, axis=0)                      # (n, F, d)
        _, g_lam, g_x = f(lam, np.repeat(xs, J, axis=0).T, np.concatenate(list(A), axis=1),
                          np.tile(D.b, (K, 1)).T)
        return (np.asarray(g_lam).T.reshape(K, J, F), np.asarray(g_x).T.reshape(K, J, d))

    def transition_margins(self, z: Layout) -> tuple[np.ndarray, np.ndarray]:
        """Lemma-1 margins of both ends of every transition and hazard (scaled
        units; >= 0 is clear): (start (K, J), end (K, J))."""
        D = self.data
        K, J = D.K, D.J
        n = K * J
        lam = z.lam.reshape(n, D.F).T
        A = np.repeat(D.A[None], K, axis=0).reshape(n, D.F, D.d)
        b = np.tile(D.b, (K, 1)).T
        Ah = np.concatenate(list(A), axis=1)                                    # F x (n d)
        x_end = np.repeat(z.x[1:], J, axis=0).T
        Y_end = np.concatenate(list(np.repeat(z.Q[1:], J, axis=0)), axis=1)
        end = np.asarray(self.f_end_margin.map(n)(x_end, Y_end, lam, Ah, b)).reshape(K, J)
        x_st = np.repeat(z.x[:-1], J, axis=0).T
        start = np.empty((K, J))
        if K > 1:
            m = (K - 1) * J
            Y_st = np.concatenate(list(np.repeat(z.Y[1:-1], J, axis=0)), axis=1)
            start[1:] = np.asarray(self.f_end_margin.map(m)(
                x_st[:, J:], Y_st, lam[:, J:], Ah[:, J * D.d:], b[:, J:])).reshape(K - 1, J)
        P0h = np.concatenate([D.P0] * J, axis=1)
        start[0] = np.asarray(self.f_start_margin_P.map(J)(
            x_st[:, :J], P0h, lam[:, :J], Ah[:, : J * D.d], b[:, :J])).reshape(J)
        return start, end

    def target_margins(self, z: Layout) -> np.ndarray:
        """Containment margin of the final posterior per target face (scaled units)."""
        D = self.data
        N = D.At.shape[0]
        f = self.f_containment.map(N)
        return np.asarray(f(np.tile(z.x[-1][:, None], (1, N)), np.concatenate([z.Y[-1]] * N, axis=1),
                            D.At.T, D.bt[None, :])).ravel()

    def kalman_gaps(self, z: Layout) -> np.ndarray:
        """Smallest eigenvalue of Q_k^-1 - Y_{k-1}^-1 - W for k = 2..K (>= 0 feasible)."""
        K = self.data.K
        if K < 2:
            return np.zeros(0)
        f = self.f_kalman.map(K - 1)
        g = np.asarray(f(np.concatenate(list(z.Q[2:]), axis=1), np.concatenate(list(z.Y[1:-1]), axis=1)))
        mats = _sym(np.stack(np.split(g, K - 1, axis=1)))
        return np.linalg.eigvalsh(mats)[:, 0]

    def kalman_relative_gap(self, z: Layout) -> float:
        """max_k ||Q_k^-1 - (Y_{k-1}^-1 + W)|| / ||Q_k^-1|| over k >= 2: how far the
        relaxation (prob_2) is from the Kalman equality (Lemma 2 says 0 at the optimum)."""
        D = self.data
        if D.K < 2:
            return 0.0
        Pq = np.linalg.inv(z.Q[2:])
        Pk = np.linalg.inv(z.Y[1:-1]) + D.W
        return float(np.max(np.linalg.norm(Pq - Pk, axis=(1, 2)) / np.linalg.norm(Pq, axis=(1, 2))))

    # ------------------------------------------------------ conversions
    def tighten(self, z: Layout) -> Layout:
        """Replace Q by the Kalman recursion from S (Lemma 2): stays feasible
        (every ellipse shrinks) and never increases the cost."""
        D = self.data
        out = z.copy()
        out.Q[1] = D.Q1
        for k in range(2, D.K + 1):
            Pk = np.linalg.inv(out.Q[k - 1] + out.S[k - 1])
            out.Q[k] = _sym(np.linalg.inv(Pk + D.W))
        return out

    def to_path(self, z: Layout, meta: dict | None = None):
        """BeliefPath in SI units (Kalman-consistent: priors rolled out from S)."""
        from ..path import BeliefPath

        D = self.data
        s2 = D.sigma**2
        S_si = z.S / s2
        S_si[0] = 0.0
        return BeliefPath.from_sensing(z.x * D.sigma, self.scenario.P0, S_si, W=self.scenario.W,
                                       noise="per_step", meta=dict(meta or {}))

    def from_path(self, path, lam_si: np.ndarray) -> Layout:
        """Layout from a per-step BeliefPath (SI) and its certificates (K, J, F) in SI."""
        D = self.data
        s2 = D.sigma**2
        x = path.x / D.sigma
        S = path.S * s2
        S[0] = 0.0
        Q = np.zeros_like(S)
        Q[1:] = np.linalg.inv(path.P_prior[1:] / s2)
        Q = _sym(Q)
        return Layout(x, Q, _sym(S), lam_si * D.sigma)
