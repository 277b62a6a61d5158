"""Turn any belief path into a feasible initial point of the smoothing model.

Steps (paper section IV.B, "Initialization", done exactly rather than by an
SDP feasibility problem):

1. Map the path's means onto K steps. By default one step per path edge
   (``K=None``). With ``K`` larger than the number of edges, each edge is cut
   into equal pieces, steps allotted to edges in proportion to their length
   (every edge keeps at least one step), so the polyline -- and hence the
   geometry the planner checked -- is unchanged. K smaller than the number
   of edges is refused (dropping vertices could cut corners through
   obstacles).
2. Re-derive the covariances for the smoother's noise model (W per step,
   paper eq. 2). With ``sensing="minimal"`` (default) no sensing is taken
   over from the path: each posterior starts as its prior P_{k-1} + W (no
   measurement) and is only shrunk where needed. With ``sensing="path"`` the
   posterior at each node is the largest covariance below both the new prior
   and the path's own posterior there (the authors' "matrix minimum"), i.e.
   the path's sensing is kept and more is added where needed. In both cases,
   where a transition is not clear (the per-step model can be noisier than
   the planner's per-metre model), the posterior at its start is halved --
   more sensing at k-1 -- until it is, and the final posterior is halved
   until its ellipse lies in the target. "minimal" is the default because
   planner paths often carry near-exact posteriors (P ~ 1e-9 I, i.e.
   S ~ 1e9 m^-2) that add nothing to feasibility and made the first conic
   subproblem fail on paper-multi (alpha = 1, K = 20: InsufficientProgress
   twice with "path", converged with "minimal").
3. Certificates lam_{k,j} of Theorem 1 from the exact transition geometry
   (the optimal common lambda, which maximises the slack).
4. The result is checked by :func:`belief_nlp.verify` and by the model.

If the means themselves collide (no covariance can fix it), or the last mean
is outside the target, :class:`~belief_nlp.errors.InfeasibleStartError`
names the transition and the obstacle.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import casadi as ca
import numpy as np

from .. import belief
from ..errors import InfeasibleStartError, ValidationError
from ..geometry import PolytopeSet, containment_margin, transition_minimiser
from ..model import terms
from ..model.evaluate import _hcat
from .policy import DEFAULT_POLICY
from ..path import BeliefPath, result_path
from ..scenario import Scenario
from ..verify import VerificationReport, verify

__all__ = ["WarmStart", "warm_start", "resample_means", "allocate_steps", "sharpened", "certificates",
           "segment_certificates"]

# Clearance margin required of the start point, relative to chi2, so that
# solver rounding in the first subproblem never meets an active constraint
# exactly (numerics.md: constraints end active at ~1e-7).
_START_MARGIN = DEFAULT_POLICY.warm_start
_MAX_HALVINGS = 60
# candidates of the halving loop checked in one batch (a batch's rows cost
# ~2 % of a call each: 1 row 1.05 ms, 8 rows 1.18 ms at K = 20)
_HALVING_BATCH = 4


@dataclass
class WarmStart:
    """A feasible start of the smoother, built by :func:`warm_start`.

    Parameters
    ----------
    path : BeliefPath
        The per-step path (SI units) the smoother starts from.
    lam : ndarray, shape (K, J, F)
        Certificates of Theorem 1 in SI units (padded faces zero), hazards
        ordered as ``scenario.hazards``.
    report : VerificationReport or None
        Independent verification of ``path`` (None when built with
        ``verify_start=False``).
    added_sensing : int, optional
        Number of covariance halvings applied to make transitions clear.
    allocation : {"length", "feasibility"}, optional
        How steps were allotted to the path's edges: in proportion to edge
        length, or by ``allocate_steps`` after the first was infeasible.
    """

    path: BeliefPath
    lam: np.ndarray
    report: VerificationReport | None
    added_sensing: int = 0
    allocation: str = "length"      # how steps were allotted to edges: "length" or "feasibility"

    @property
    def K(self) -> int:
        """Number of time steps (transitions) of the warm start."""
        return self.path.K


def _split(x: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Means with edge e of the polyline cut into steps[e] equal pieces."""
    pts = [x[0]]
    for e in range(x.shape[0] - 1):
        t = np.arange(1, steps[e] + 1) / steps[e]
        pts.extend(x[e] + t[:, None] * (x[e + 1] - x[e]))
    return np.array(pts)


def allocate_steps(scenario: Scenario, x: np.ndarray, K: int, hazards: PolytopeSet | None = None,
                   chi2: float | None = None) -> np.ndarray | None:
    """Steps per edge (summing to K) such that every sub-transition can be made
    clear, or None when no such allocation is found.

    A sub-step ending next to an obstacle fails whatever sensing precedes it
    when the step's own noise W already reaches the obstacle; such an edge
    must not be cut finer there. A sub-transition is *possible* when it is
    clear with a near-exact start (P_prev = 1e-9 W; the first step starts from
    P0). Extra steps go, one at a time, to the edge with the longest sub-step
    among those whose finer split stays possible (open space gets the steps,
    tight passages keep long steps)."""
    hazards = hazards or PolytopeSet.cached(scenario.hazards)
    x = np.asarray(x, float)
    E = x.shape[0] - 1
    W = scenario.W
    thr = (scenario.chi2 if chi2 is None else chi2) * (1 + _START_MARGIN)
    lengths = np.linalg.norm(np.diff(x, axis=0), axis=1)
    cache: dict = {}

    def possible(e: int, n: int) -> bool:
        if (e, n) not in cache:
            t = np.arange(n + 1) / n
            pts = x[e] + t[:, None] * (x[e + 1] - x[e])
            P = np.broadcast_to(1e-9 * W, (n, *W.shape)).copy()
            if e == 0:
                P[0] = scenario.P0
            tm = transition_minimiser(pts[:-1], P, pts[1:], W, hazards, threshold=thr)
            cache[(e, n)] = bool(np.all(tm.dist2 >= thr))
        return cache[(e, n)]

    steps = np.ones(E, dtype=int)
    if not all(possible(e, 1) for e in range(E)):
        return None
    for _ in range(K - E):
        open_ = [e for e in range(E) if possible(e, steps[e] + 1)]
        if not open_:
            return None
        e = max(open_, key=lambda i: lengths[i] / steps[i])
        steps[e] += 1
    return steps


def resample_means(x: np.ndarray, K: int | None) -> np.ndarray:
    """Means on K steps along the polyline x, keeping every vertex (see module doc)."""
    x = np.asarray(x, float)
    n_edges = x.shape[0] - 1
    if K is None or K == n_edges:
        return x.copy()
    if not isinstance(K, (int, np.integer)) or K < 1:
        raise ValidationError("K", f"must be a positive integer, got {K!r}")
    if K < n_edges:
        raise ValidationError("K", f"the path has {n_edges} edges; K = {K} would drop vertices "
                                   "(choose K >= the number of edges or K=None)")
    lengths = np.linalg.norm(np.diff(x, axis=0), axis=1)
    steps = np.ones(n_edges, dtype=int)
    extra = K - n_edges
    # largest-remainder allocation of the extra steps by length
    share = lengths / max(lengths.sum(), 1e-300) * K
    for _ in range(extra):
        steps[np.argmax(share - steps)] += 1
    return _split(x, steps)


def _target_posteriors(path: BeliefPath, x_new: np.ndarray) -> np.ndarray:
    """Path posterior at each new node: at old vertices their own, inside an
    edge the matrix minimum of the two ends (the smaller ellipse)."""
    x_old = path.x
    if x_new.shape == x_old.shape and np.array_equal(x_new, x_old):
        return path.P.copy()             # the same nodes (a re-plan's K): the loop below gives exactly this
    out = np.empty((x_new.shape[0], path.dim, path.dim))
    j = 0
    for i, p in enumerate(x_new):
        while j < x_old.shape[0] - 1 and not np.allclose(p, x_old[j]) and not _on_segment(p, x_old[j], x_old[j + 1]):
            j += 1
        if np.allclose(p, x_old[j]):
            out[i] = path.P[j]
        elif j + 1 < x_old.shape[0] and np.allclose(p, x_old[j + 1]):
            out[i] = path.P[j + 1]
        else:
            out[i] = belief.matrix_minimum(path.P[j], path.P[min(j + 1, x_old.shape[0] - 1)])
    return out


def _on_segment(p, a, b) -> bool:
    ab = b - a
    L2 = float(ab @ ab)
    if L2 == 0:
        return bool(np.allclose(p, a))
    t = float((p - a) @ ab) / L2
    return -1e-12 <= t <= 1 + 1e-12 and np.allclose(a + t * ab, p, atol=1e-12)


def warm_start(scenario: Scenario, path: Any, K: int | None = None,
               sensing: str = "minimal", chi2: float | None = None, *, verify_start: bool = True) -> WarmStart:
    """A feasible initial point of the smoother built from ``path``.

    The means are mapped onto K steps (the polyline is kept), the
    covariances re-derived for the per-step noise model with as little
    sensing as keeps every transition clear and the final ellipse in the
    target, and the Theorem-1 certificates computed; the result is verified
    (module :mod:`belief_nlp.smoother.warmstart` gives the details).

    Parameters
    ----------
    scenario : Scenario
        The planning problem.
    path : BeliefPath or a result with a ``.path``
        A path from the planner (either noise model; a PlanResult is taken
        as its path, a failed one refused with its message), or a user's
        polyline with covariances (:meth:`BeliefPath.from_covariances`); it
        must start at the scenario's start mean.
    K : int, optional
        Number of time steps; None gives one step per path edge. With more
        steps than edges, steps are first allotted in proportion to edge
        length, and if that start is infeasible by ``allocate_steps``
        (``WarmStart.allocation`` says which). Fewer steps than edges are
        refused.
    sensing : {"minimal", "path"}, optional
        ``"minimal"`` (default): no sensing is taken over from the path, each
        posterior starts as its prior and is shrunk only where needed;
        ``"path"``: the path's sensing is kept and more added where needed.
    chi2 : float, optional
        The collision level every transition must clear (None: the
        scenario's); the target keeps the scenario's own level. A risk
        budget's warm start tries a ladder of levels here
        (:mod:`belief_nlp.smoother.budget_start`).
    verify_start : bool, optional
        Verify the warm start independently (default). False leaves
        ``report`` None: :func:`belief_nlp.smooth` does so, because its
        exact check proves the start safe and it verifies the path it
        returns, the warm start included (one verification less per call).

    Returns
    -------
    WarmStart
        The path, its certificates and its verification.

    Raises
    ------
    InfeasibleStartError
        When the means themselves collide or the last mean is outside the
        target; it names the transition and the obstacle.
    ValidationError
        For bad arguments (a K below the number of edges, an unknown ``sensing``).
    """
    inner = result_path(path)                   # PlanResult, SmoothResult: their path
    path = path if inner is None else inner
    try:
        return _warm_start(scenario, path, K, sensing, None, chi2, verify_start)
    except InfeasibleStartError:
        if K is None or not isinstance(path, BeliefPath) or K <= path.K:
            raise
        steps = allocate_steps(scenario, path.x, K, chi2=chi2)
        if steps is None:
            raise
        ws = _warm_start(scenario, path, K, sensing, steps, chi2, verify_start)
        ws.allocation = "feasibility"
        return ws


def _warm_start(scenario: Scenario, path: BeliefPath, K: int | None, sensing: str,
                steps: np.ndarray | None, chi2_collision: float | None = None, check: bool = True) -> WarmStart:
    """:func:`warm_start` with the means cut by ``steps`` per edge (None: by length)."""
    if not isinstance(path, BeliefPath):
        raise ValidationError("path", f"must be a BeliefPath, got {type(path).__name__}")
    if path.dim != scenario.dim:
        raise ValidationError("path", f"dimension {path.dim} does not match the scenario's {scenario.dim}")
    if sensing not in ("minimal", "path"):
        raise ValidationError("sensing", f"must be 'minimal' or 'path', got {sensing!r}")
    if not np.allclose(path.x[0], scenario.x0, atol=1e-9):
        raise ValidationError("path.x", "the path must start at the scenario's start mean x0")
    x = resample_means(path.x, K) if steps is None else _split(np.asarray(path.x, float), steps)
    K_ = x.shape[0] - 1
    target_P = _target_posteriors(path, x) if sensing == "path" else None     # "minimal" never reads it
    chi2 = scenario.chi2                                     # the target's level
    chi2_c = chi2 if chi2_collision is None else float(chi2_collision)
    hazards = PolytopeSet.cached(scenario.hazards)
    # each transition's level: chi2_c, transition 1 at the start's own (start_confidence)
    levels = np.full((K_, 1), chi2_c)
    levels[0] = min(chi2_c, scenario.chi2_start)
    thr_k = levels * (1 + _START_MARGIN)
    W = scenario.W
    P = np.empty((K_ + 1, scenario.dim, scenario.dim))
    P[0] = scenario.P0
    halvings = 0

    def step(k: int) -> None:            # the posterior after transition k, from P[k - 1]
        P_prior = P[k - 1] + W
        P[k] = belief.matrix_minimum(P_prior, target_P[k]) if sensing == "path" else P_prior

    k = 1
    while k <= K_:
        # every transition from k on in one batch, with the posteriors the loop
        # below gives when none needs more sensing (the common case); the loop
        # runs from the first transition that is not clear
        for i in range(k, K_ + 1):
            step(i)
        thr = thr_k[k - 1:]
        dist2 = transition_minimiser(x[k - 1:-1], P[k - 1:-1], x[k:], W, hazards, threshold=float(thr[-1, 0])).dist2
        if k == 1 and thr[0, 0] != thr[-1, 0]:
            # a value is exact only on its own side of the threshold it was decided
            # against: transition 1 at its start level, by a call of its own
            dist2[0] = transition_minimiser(x[:1], P[:1], x[1:2], W, hazards, threshold=float(thr[0, 0])).dist2[0]
        not_clear = np.flatnonzero(np.any(dist2 < thr, axis=1))
        if not_clear.size == 0:
            break
        k += int(not_clear[0])
        # P[k - 1] halved until transition k is clear: the candidates P, P/2,
        # P/4, ... (each the half of the one before, as one halving at a time
        # gives them) checked in one batch, taken in order -- the first clear
        # one, or the first at which a halving is refused, decides (one call
        # instead of one per halving: most transitions need one to three)
        rows = _HALVING_BATCH
        thr = float(thr_k[k - 1, 0])
        while True:
            # P / 2^i: scaling by a power of two is exact, so the same bits as halving i times
            cand = P[k - 1][None] * (0.5 ** np.arange(rows))[:, None, None]
            tm = transition_minimiser(np.repeat(x[k - 1][None], rows, axis=0), cand,
                                      np.repeat(x[k][None], rows, axis=0), W, hazards, threshold=thr)
            clear = np.flatnonzero(~np.any(tm.dist2 < thr, axis=1))
            n = int(clear[0]) if clear.size else rows          # halvings within this batch
            for i in range(n):                                 # each refused halving raises as before
                if k == 1 or halvings > _MAX_HALVINGS * K_ \
                        or np.max(np.linalg.eigvalsh(cand[i])) < 1e-14 * max(1.0, np.trace(W)):
                    j = int(np.nonzero(tm.dist2[i] < thr)[0][0])
                    raise InfeasibleStartError(
                        f"transition {k} (from {x[k - 1].round(6).tolist()} to {x[k].round(6).tolist()}) "
                        f"cannot be made clear of {scenario.hazards[j].name} under the smoother's per-step noise "
                        f"W: the means pass too close (no sensing before the step can shrink P + W enough)"
                        + (". The path was planned with per-metre noise; plan with noise='per_step' to get "
                           "paths feasible for the smoother's model" if path.noise == "per_metre" else ""),
                        transition=k, obstacle=scenario.hazards[j].name)
                halvings += 1
            if clear.size:
                P[k - 1] = cand[n]
                break
            P[k - 1] = 0.5 * cand[-1]
            rows = 2 * _HALVING_BATCH                          # a long run of halvings: larger batches
        step(k)
        k += 1
    # final posterior inside the target
    T = scenario.target
    if not T.contains(x[-1]):
        raise InfeasibleStartError("the path's last mean is outside the target", transition=K_, obstacle="target")
    while containment_margin(x[-1], P[-1], T.A, T.b, chi2) < 1e-9:
        P[-1] = 0.5 * P[-1]
        halvings += 1
        if halvings > _MAX_HALVINGS * (K_ + 1):
            raise InfeasibleStartError("cannot fit the final ellipse into the target", transition=K_, obstacle="target")
    P_prior = np.empty_like(P)
    P_prior[0] = P[0]
    P_prior[1:] = P[:-1] + W
    S = np.zeros_like(P)
    S[1:] = belief.lossless_sensing(P_prior[1:], P[1:])
    S = 0.5 * (S + np.swapaxes(S, -1, -2))
    # clip tiny negative eigenvalues from rounding: sensing is PSD by construction
    w, V = np.linalg.eigh(S)
    S = (V * np.maximum(w, 0.0)[..., None, :]) @ np.swapaxes(V, -1, -2)
    ws_path = BeliefPath.from_sensing(x, scenario.P0, S, W=W, noise="per_step",
                                      meta={**path.meta, "warm_start_from": path.meta.get("source", "path")})
    lam = certificates(scenario, ws_path, hazards, chi2=levels)
    report = verify(scenario, ws_path, levels=np.broadcast_to(levels, (K_, len(hazards)))) if check else None
    if report is not None and not report.safe:
        raise InfeasibleStartError(f"warm start failed verification: {report.summary()}")
    return WarmStart(ws_path, lam, report, halvings)


def scaled_posteriors(scenario: Scenario, path: BeliefPath, factor: float) -> BeliefPath:
    """``path`` with every posterior after the start scaled by ``factor`` (the
    priors follow from the per-step noise W); no certificates, no check."""
    P = path.P.copy()
    P[1:] *= factor
    return BeliefPath.from_covariances(path.x, P, W=scenario.W, noise="per_step", meta=path.meta)


def sharpened(scenario: Scenario, warm: WarmStart, factor: float, chi2: float) -> WarmStart:
    """``warm`` with every posterior after the start scaled by ``factor`` (< 1:
    more sensing at every step; P_k <= P_{k-1} + W keeps holding, every
    ellipse shrinks, so the path stays safe at ``chi2``), certificates and
    verification redone. The continuous-time budget's warm start uses it: its
    surrogate covariances P_prior_{k-1} + W shrink only with earlier sensing."""
    path = scaled_posteriors(scenario, warm.path, factor)
    lam = certificates(scenario, path, chi2=chi2)
    report = verify(scenario, path, levels=chi2)
    if not report.safe:
        raise InfeasibleStartError(f"warm start failed verification: {report.summary()}")
    return WarmStart(path, lam, report, warm.added_sensing, warm.allocation)


@lru_cache(maxsize=16)
def _margin_parts(F: int, d: int) -> ca.Function:
    """(x, P, lam, A, b) -> (quad(A^T lam, P), bilinear(lam, x, A, b)) for one pair,
    from the model's terms; ``.map(n)`` evaluates it over stacked columns."""
    x, P, lam = ca.SX.sym("x", d), ca.SX.sym("P", d, d), ca.SX.sym("lam", F)
    A, b = ca.SX.sym("A", F, d), ca.SX.sym("b", F)
    return ca.Function("margin_parts", [x, P, lam, A, b], [terms.quad(ca.mtimes(A.T, lam), P),
                                                           terms.bilinear(lam, x, A, b)])


@lru_cache(maxsize=16)
def _margin_map(F: int, d: int, n: int) -> ca.Function:
    """:func:`_margin_parts` mapped over n pairs, built once per shape (a
    re-plan in a loop asks for the same one every time)."""
    return _margin_parts(F, d).map(n)


def certificates(scenario: Scenario, path: BeliefPath, hazards: PolytopeSet | None = None,
                 margin: float = _START_MARGIN, chi2: float | np.ndarray | None = None) -> np.ndarray:
    """Theorem-1 certificates (K, J, F), SI units, for every transition of a path.

    The margin-maximising lambda* (the maximiser of the Lemma-1 dual at the
    worst s) grows like distance / variance, which is huge next to a tiny
    start covariance (P0 = 1e-9 I) and makes the next conic subproblem badly
    scaled. Both end conditions are concave in a scaling t of lambda*, so we
    return the smallest t * lambda* that still leaves a comfortable slack,
    f_s(t lambda*) >= chi2 + min(chi2, (g* - chi2) / 2) at s = 0 and s = 1
    (g* = min_s dist2; t = 1 when the transition has less slack than
    chi2 * margin). Strictly interior certificates keep the interior-point
    solver away from the boundary of every cone at once.
    """
    hazards = hazards or PolytopeSet.cached(scenario.hazards)
    chi2 = scenario.chi2 if chi2 is None else chi2
    return segment_certificates(path.x[:-1], path.P[:-1], path.x[1:], path.transition_noise, hazards, chi2, margin)


def segment_certificates(x0: np.ndarray, P0: np.ndarray, x1: np.ndarray, Wn: np.ndarray, hazards: PolytopeSet,
                         chi2: float | np.ndarray, margin: float = _START_MARGIN) -> np.ndarray:
    """:func:`certificates` for transitions given as arrays -- means x0 -> x1
    (K, d), covariance P(s) = P0 + s Wn ((K, d, d) each) -- in any consistent
    units (the hazards' too): the continuous-time surrogate uses it with
    P0 = Sigma_k and Wn = 0."""
    P1 = P0 + Wn
    tm = transition_minimiser(x0, P0, x1, Wn, hazards, want_lam=True)
    lam = tm.lam                                                # (K, J, F)
    chi2 = np.asarray(chi2, float)                              # collision level(s)
    target = chi2 + np.maximum(chi2 * margin, np.minimum(chi2, 0.5 * (tm.dist2 - chi2)))
    # the two parts of the Lemma-1 margin at each end, from the model's terms:
    # margin(t lam) = -t^2 quad(A^T lam, P) + t bilinear(lam, x) - chi2
    K, J, F = lam.shape
    A = np.tile(hazards.A, (K, 1, 1))
    t_min = np.zeros((K, J))
    parts = _margin_map(F, x0.shape[1], K * J)
    for xe, Pe in ((x0, P0), (x1, P1)):
        a, h = parts(np.repeat(xe, J, axis=0).T, _hcat(np.repeat(Pe, J, axis=0)), lam.reshape(K * J, F).T,
                     _hcat(A), np.tile(hazards.b, (K, 1)).T)
        a = a.full().reshape(K, J)
        beta = 0.5 * h.full().reshape(K, J)
        with np.errstate(divide="ignore", invalid="ignore"):
            disc = beta**2 - a * target
            t_lo = np.where(a > 0, (beta - np.sqrt(np.maximum(disc, 0.0))) / a, target / (2 * beta))
        t_lo = np.where(np.isfinite(t_lo) & (disc >= 0), t_lo, 1.0)
        t_min = np.maximum(t_min, t_lo)
    t = np.clip(t_min, 0.0, 1.0)
    return lam * t[..., None]
