"""Rigorous lower bounds on a transition's clearance: Theorem-1 certificate values.

For a hazard {y : A y <= b} and any lam >= 0,

    f_s(lam) = -lam^T A P(s) A^T lam + 2 lam^T (A x(s) - b)

is at most dist2(x(s), P(s)) (Lemma 1, weak duality), and f_s(lam) is
affine in s, so min(f_0(lam), f_1(lam)) is at most the minimum over s in
[0, 1] (Theorem 1). The bound needs nothing from the minimiser but a finite
lam >= 0: a wrong face choice, a near-degenerate hull or an iteration limit
can only make it weak, never wrong. That is why the oracle's lower bound is
this value alone: the bracket's tangent bound is rigorous only when every
evaluation found the true dist2 (a missed face makes it an overestimate),
and for the minimiser's certificate -- the end certificates mixed so that
the value is flat in s (:func:`.minimise._mix_certificates`) -- the value is
already >= that tangent bound whenever the evaluations are exact.

Rounding: each value is lowered by a bound on its floating-point error,
proportional to the magnitudes summed (|A|^T lam, |P|, |A| |x| + |b|), not
to the value itself -- for a needle covariance (condition 1e9) the
quadratic term cancels to ~eps * cond relative, and the bound says so.
"""

from __future__ import annotations

import numpy as np

from .planar import _small_k_matmul

_EPS = np.finfo(float).eps


def certificate_lower(A: np.ndarray, b: np.ndarray, x0: np.ndarray, P0: np.ndarray, x1: np.ndarray,
                      W: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """min(f_0(lam), f_1(lam)) (n, m) minus its rounding bound, floored at 0.

    ``A`` (m, F, d), ``b`` (m, F) (padded faces are inert: a zero row with
    b = 1), ``x0``, ``x1`` (n, d), ``P0``, ``W`` (n, d, d), ``lam`` (n, m, F).
    Entries of lam < 0 are treated as 0; a non-finite value gives 0 (no
    claim), so the result is always a valid lower bound on the minimum over
    s in [0, 1] of the squared Mahalanobis distance to each polytope.
    Few numpy calls (the planner's batches are small), batched products
    kept under the GEMM threading threshold (see :mod:`.planar`).
    """
    n, (m, F, d) = lam.shape[0], A.shape
    lam = np.maximum(lam, 0.0)                                    # NaN stays NaN -> no claim
    absA = np.abs(A)
    lam_m = lam.transpose(1, 0, 2)                                # (m, n, F): one small GEMM per polytope
    v = np.matmul(lam_m, A).transpose(1, 0, 2)                    # A^T lam (n, m, d)
    u = np.matmul(lam_m, absA).transpose(1, 0, 2)                 # |A|^T lam >= |v|

    def rows(M, x):                                               # M x (n, m, F) for M (m, F, d)
        return _small_k_matmul(x, M.reshape(m * F, d).T).reshape(n, m, F)

    def dot(a, c):
        return np.einsum("nmk,nmk->nm", a, c)

    # magnitudes that bound both ends: |P(s)| <= |P0| + |W|, |x(s)| <= |x0| + |x1|
    Pa = np.abs(P0) + np.abs(W)
    # the computed v is within gamma_F u of A^T lam, so |A^T lam| <= va
    va = np.abs(v) + 1.5 * F * _EPS * u
    qv = dot(np.matmul(va, Pa), va)
    qm = dot(np.matmul(va, Pa), u)
    qa = dot(np.matmul(u, Pa), u)
    lin_a = dot(lam, rows(absA, np.abs(x0) + np.abs(x1)) + np.abs(b))
    # first-order error bounds (Higham's gamma_n ~ n eps), 1.5x for the
    # second-order terms and the rounding of these magnitudes themselves:
    # v = A^T lam (F terms, error e <= gamma_F u) perturbs q = v^T P v by
    # 2 |v|^T |P| |e| + |e|^T |P| |e|, which is 2 gamma_F |v|^T|P|u to first
    # order -- not u^T|P|u: at a sliver's sharp vertex lam is large and
    # A^T lam cancels, so u >> |v| (5e-5 relative too pessimistic, seen);
    # q sums d^2 triple products (and P1 = P0 + W is rounded), A x - b has
    # d + 1 terms and lam^T r F more, and the final -q + 2 lin one rounding each
    err = 1.5 * _EPS * ((d * d + 3) * qv + 2 * F * qm + 2.0 * (F + d + 1) * lin_a) + (1.5 * F * _EPS) ** 2 * qa
    f0 = 2.0 * dot(lam, rows(A, x0) - b) - dot(np.matmul(v, P0), v)
    f1 = 2.0 * dot(lam, rows(A, x1) - b) - dot(np.matmul(v, P0 + W), v)
    out = np.minimum(f0, f1)
    out = out - err - 2.0 * _EPS * np.abs(out)
    return np.where(np.isfinite(out), np.maximum(out, 0.0), 0.0)


def decide(lower: np.ndarray, upper: np.ndarray, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """(clear, decided) against ``threshold``: clear iff the lower bound
    clears it; decided iff clear or the upper bound (a real point at a real
    s) is below it. An undecided pair is never clear."""
    clear = lower >= threshold
    return clear, clear | (upper < threshold)
