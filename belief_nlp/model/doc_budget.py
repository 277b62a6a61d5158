"""The risk budget's pieces of the CCP step (:mod:`.doc`): each pair's level
as a function of its log risk, the level's quadratic majorant, and the
exact exponential-cone budget (docs/numerics.md, "Risk allocation in the
CCP step")."""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..allocation import tail
from .cones import ConeFamily, _pick
from .data import ProblemData

__all__ = ["level_curvature_bound"]


def _level_functions() -> ca.Function:
    """tau~ -> (l~, h'(l~), h''(l~)) for the level as a function of the log risk,
    h(l) = tau with g(tau) = exp(l): l~ = log g(tau~), h' = -2 s q / phi(s),
    h'' = 2 q / phi(s) (q (1 + s^2) / phi(s) - s), s = sqrt(tau~), q = g(tau~)."""
    tau = ca.SX.sym("tau")
    s = ca.sqrt(tau)
    q = 0.5 * (1 - ca.erf(s / np.sqrt(2)))
    phi = ca.exp(-tau / 2) / np.sqrt(2 * np.pi)
    return ca.Function("level_of_log_risk", [tau], [ca.log(q), -2 * s * q / phi,
                                                   2 * q / phi * (q * (1 + tau) / phi - s)])


def level_curvature_bound(budget: float) -> float:
    """max of h''(l) = d^2 tau / dl^2 over l <= log(budget) (h'' rises with l up
    to q ~ 0.2, then falls): the curvature of the level majorant where the log
    risk rises. A dense grid with 5 % to spare (h is smooth; every iterate is
    checked exactly anyway, so the bound only decides acceptance)."""
    from scipy.special import ndtri
    from scipy.stats import norm

    q = np.geomspace(1e-16, budget, 20001)
    s = -ndtri(q)
    phi = norm.pdf(s)
    hpp = 2 * q / phi * (q * (1 + s**2) / phi - s)
    return 1.05 * float(np.max(hpp))


def _level_majorant(D: ProblemData, B, z: ca.SX, tau_t: ca.SX) -> tuple[ca.SX, list]:
    """The pairs' levels as functions of their log risks l (budget mode):
    tau = h(l) is convex in l with h'' rising in l (up to q ~ 0.2), so with
    dl = l - l~, up >= max(dl, 0), dn >= max(-dl, 0),

        tau <= tau~ + h'(l~) dl + M_up/2 up^2 + h''(l~)/2 dn^2

    (M_up = :func:`level_curvature_bound`), tight at the point in value and
    slope. Returns the affine part (K, J) and the two quadratic parts' roots."""
    K, J = D.K, D.J
    dl, up, dn = (_pick(z, M) for M in (B.ell, B.up, B.dn))
    _, h1, h2 = _level_functions().map(K * J)(tau_t.T)
    h1, h2 = (ca.reshape(v, J, K).T for v in (h1, h2))
    tt = ca.reshape(tau_t, J, K).T
    aff = tt + h1 * dl
    m_up = np.sqrt(level_curvature_bound(float(D.budget)))
    return aff, [m_up * up, ca.sqrt(h2) * dn]


def _budget_families(D: ProblemData, B, z: ca.SX, tau_t: ca.SX) -> list[ConeFamily]:
    """sum_kj exp(l_kj) <= budget exactly (exponential cones, in units of an
    even share s = budget / (K J): exp(l - log s) <= e, sum e / (K J) <= 1), the epigraphs up/dn of the
    log risk's step from the point, and log(floor) <= l <= log(budget): a pair's
    level stays in [tau_lo, tau_hi] (:func:`belief_nlp.allocation.level_bounds`).
    The step stays a DPP cone program."""
    tau_lo, tau_hi = D.level_bounds
    dl, e, up, dn = (_pick(z, M.ravel()[:, None]) for M in (B.ell, B.e, B.up, B.dn))
    n = int(dl.numel())
    lt = _level_functions().map(n)(tau_t.T)[0].T
    ell = lt + dl                                # the variable is the step (no large constants)
    lb = float(np.log(tail(tau_hi)))
    share = D.budget / n                         # e in units of an even share: O(1) where it matters
    exp_rows = ca.vertcat(*[ca.vertcat(ell[i] - np.log(share), 1, e[i]) for i in range(n)])
    return [ConeFamily("budget_exp", "exp", 3, n, exp_rows),
            ConeFamily("budget_steps", "nonneg", 1, 4 * n, ca.vertcat(up - dl, up, dn + dl, dn)),
            ConeFamily("budget_levels", "nonneg", 1, 2 * n, ca.vertcat(ell - lb, np.log(D.budget) - ell)),
            ConeFamily("budget_total", "nonneg", 1, 1, 1 - ca.sum1(e) / n)]
