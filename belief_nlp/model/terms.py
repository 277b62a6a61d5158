"""Every term of the paper's DOC program (eq. main_doc, with the README's
corrections C1-C8), written once as CasADi expressions.

Each function takes CasADi symbols or numbers (SX, MX or DM) and returns an
expression; the symbolic model (:mod:`.doc`) composes them over all steps and
hazards, and every solver form is derived from that composition: the CCP
subproblem's cones (:mod:`.conic_form`), the NLP of IPOPT and the other
CasADi solvers (:mod:`.nlp_form`) and the functions exported for MPC
(:mod:`belief_nlp.export`). The formulas are unit-free: they hold in metres
and in the model's scaled units alike (lambda scales inversely with length).

Notation: hazard {y : A y <= b} (rows = faces), certificate lam >= 0, its
direction v = A^T lam, chi2 the confidence level, Y = Q + S posterior
information, Q prior information.
"""

from __future__ import annotations

import casadi as ca

__all__ = [
    "bilinear", "quad", "quad_inv", "h1_lmi", "h2", "collision_margin_inv", "collision_margin_cov",
    "kalman_lmi", "kalman_residual", "logdet", "logdet_epigraph_lmi", "target_lmis",
    "target_margin", "target_margin_cov", "target_margin_sq", "target_margin_sq_cov", "control", "information", "predict", "update_cov",
    "information_cov",
]


def bilinear(lam, x, A, b):
    """h(lam, x) = 2 lam^T (A x - b): the bilinear part of h2 (C6), concave-
    convex indefinite; CCP splits it around the current point."""
    return 2 * ca.dot(lam, ca.mtimes(A, x) - b)


def quad(v, P):
    """v^T P v (the k = 1 start end, C8: P0 is used directly, never inverted)."""
    return ca.dot(v, ca.mtimes(P, v))


def quad_inv(v, Y):
    """v^T Y^-1 v: the smallest R with h1_lmi(R, v, Y) >= 0 (Schur complement)."""
    return ca.dot(v, ca.solve(Y, v))


def h1_lmi(R, v, Y):
    """h1 of eq. doc as an LMI: [[R, v^T], [v, Y]] >= 0  <=>  R >= v^T Y^-1 v."""
    return ca.blockcat([[R, v.T], [v, Y]])


def h2(R, lam, x, A, b, chi2):
    """h2 of eq. doc with C6: R + chi2 - 2 lam^T (A x - b) <= 0."""
    return R + chi2 - bilinear(lam, x, A, b)


def collision_margin_inv(x, Y, lam, A, b, chi2):
    """-h2 with h1 tight (R = v^T Y^-1 v): the Lemma-1 / Theorem-1 margin of one
    end, -v^T Y^-1 v + 2 lam^T (A x - b) - chi2 (>= 0 is clear; C5 keeps the
    trailing lam). Y is the end's information matrix."""
    return -h2(quad_inv(ca.mtimes(A.T, lam), Y), lam, x, A, b, chi2)


def collision_margin_cov(x, P, lam, A, b, chi2):
    """The same margin with the end's covariance P (k = 1 start, C8)."""
    return -h2(quad(ca.mtimes(A.T, lam), P), lam, x, A, b, chi2)


def kalman_lmi(Q, Y_prev, W_inv):
    """Relaxed Kalman step of prob_2 as a 2d x 2d LMI (C7):
    [[Y - Q_k, -Y], [-Y, Y + W^-1]] >= 0  <=>  Q_k <= (Y_{k-1}^-1 + W)^-1, Y = Y_{k-1}.

    It is the errata's [[W^-1 - Q_k, W^-1], [W^-1, Y + W^-1]] under the
    congruence T = [[I, -I], [0, I]] (same cone). Here every entry holds a
    variable; the errata's constant W^-1 block left rows without one, which a
    conic solver's equilibration cannot scale (docs/numerics.md,
    "Conditioning of the CCP step")."""
    return ca.blockcat([[Y_prev - Q, -Y_prev], [-Y_prev, Y_prev + W_inv]])


def kalman_residual(Q, Y_prev, W):
    """Q_k^-1 - Y_{k-1}^-1 - W: zero on the Kalman recursion (Lemma 2), >= 0 on
    the relaxed feasible set."""
    return ca.inv(Q) - ca.inv(Y_prev) - W


def logdet(M):
    """log det M (M positive definite)."""
    return ca.log(ca.det(M))


def logdet_epigraph_lmi(Q, Z):
    """[[Q, Z], [Z^T, diag Z]] >= 0 with Z lower triangular: then
    log det Q >= sum_i log Z_ii, the conic epigraph of -log det Q (with
    exponential cones u_i <= log Z_ii)."""
    return ca.blockcat([[Q, Z], [Z.T, ca.diag(ca.diag(Z))]])


def target_lmis(x, C, Y, a, bt, chi2):
    """final_cond with the sign of C4, for one target face {a^T y <= bt}:
    [[bt - a^T x, 1], [1, C / chi]] >= 0 and [[1, C a^T], [C a, Y]] >= 0, C >= 0
    (together: bt - a^T x >= chi sqrt(a^T Y^-1 a))."""
    gamma = 1.0 / ca.sqrt(chi2)
    m1 = ca.blockcat([[bt - ca.dot(a, x), 1], [1, gamma * C]])
    m2 = ca.blockcat([[ca.DM(1), C * a.T], [C * a, Y]])
    return m1, m2


def target_margin(x, Y, a, bt, chi2):
    """bt - a^T x - chi sqrt(a^T Y^-1 a) (length; >= 0: the ellipse is in the face)."""
    return bt - ca.dot(a, x) - ca.sqrt(chi2 * quad_inv(a, Y))


def target_margin_cov(x, P, a, bt, chi2):
    """The same margin with the final covariance P: bt - a^T x - chi sqrt(a^T P a)."""
    return bt - ca.dot(a, x) - ca.sqrt(chi2 * quad(a, P))


def target_margin_sq(x, Y, a, bt, chi2):
    """A smooth form defined at every iterate: (bt - a^T x) |bt - a^T x| - chi2 a^T Y^-1 a
    (length^2); >= 0 exactly when target_margin >= 0 (no square root of a
    possibly negative number)."""
    r = bt - ca.dot(a, x)
    return r * ca.fabs(r) - chi2 * quad_inv(a, Y)


def target_margin_sq_cov(x, P, a, bt, chi2):
    """target_margin_sq with the final covariance P: (bt - a^T x) |bt - a^T x| - chi2 a^T P a
    (length^2); >= 0 exactly when target_margin_cov >= 0 (for P >= 0), and
    smooth and defined for any symmetric P a solver may visit (no square root,
    no inverse)."""
    r = bt - ca.dot(a, x)
    return r * ca.fabs(r) - chi2 * quad(a, P)


def control(x_prev, x):
    """||x_k - x_{k-1}||^2, the control term of eq. main_info."""
    return ca.sumsqr(x - x_prev)


def information(Y, Q):
    """1/2 (log det Y_k - log det Q_k) nats: concave minus concave (eq. main_doc)."""
    return 0.5 * (logdet(Y) - logdet(Q))


def predict(P, W):
    """Prior covariance after one step, P + W (paper eq. 2)."""
    return P + W


def update_cov(P_hat, S):
    """Posterior covariance (P_hat^-1 + S)^-1, computed as (I + P_hat S)^-1 P_hat so
    that a (nearly) singular prior is never inverted; symmetrised."""
    P = ca.solve(ca.DM.eye(P_hat.shape[0]) + ca.mtimes(P_hat, S), P_hat)
    return 0.5 * (P + P.T)


def information_cov(P_hat, S):
    """information(Q + S, Q) with Q = P_hat^-1, as 1/2 log det(I + P_hat S)
    (matrix determinant lemma; no inverse of the prior)."""
    return 0.5 * logdet(ca.DM.eye(P_hat.shape[0]) + ca.mtimes(P_hat, S))
