"""Every safety margin of the smoother, in one place (docs/safety.md).

A transition is *certified* clear of a hazard when its Theorem-1 certificate
lam >= 0 gives, at both ends, a margin of at least ``accept`` chi2:
min(f_0(lam), f_1(lam)) - chi2 >= accept chi2 with
f_s(lam) = -lam^T A P(s) A^T lam + 2 lam^T (A x(s) - b). For any lam >= 0 that
minimum is a lower bound on min_s dist2(x(s), P(s)) (Theorem 1 / Lemma 1
duality), so the decision rests on a closed-form lower bound, never on
samples of s. The margins are ordered so that each stage leaves the next one
strict room:

    warm start (1e-6)  >  NLP rows (1e-6)  >  CCP rows (2e-7)  >  acceptance (1e-7)  >  0

The CCP step's rows ask for ``conic`` > ``accept``, so a solver answer that
is active on a row (as optima are) still clears ``accept`` after the
solver's rounding; an answer that does not is repaired by a small sensing
dose or rejected. An accepted iterate can miss the next step's rows by at most
(conic - accept) chi2 ~ 5e-7 on a pair, which moves that step's optimum by
far less than ``monotone_tol``; the warm start and the NLP keep 1e-6 so that
their points are strictly inside every row.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["SafetyPolicy", "DEFAULT_POLICY"]


@dataclass(frozen=True)
class SafetyPolicy:
    """Relative clearance margins (fractions of chi2) and the target margin.

    warm_start : margin the warm start must leave on every pair.
    nlp : margin kept in the NLP's collision rows (IPOPT).
    conic : margin kept in the CCP step's collision and containment rows.
    accept : margin a certificate must prove for an iterate to be accepted.
    target : containment margin (scaled length) required of an accepted iterate.
    """

    warm_start: float = 1e-6
    nlp: float = 1e-6
    conic: float = 2e-7
    accept: float = 1e-7
    target: float = 0.0

    def __post_init__(self) -> None:
        if not (self.warm_start >= self.conic > self.accept >= 0 and self.nlp > self.accept and self.target >= 0):
            raise ValueError("SafetyPolicy margins must satisfy warm_start >= conic > accept >= 0, nlp > accept")


DEFAULT_POLICY = SafetyPolicy()
