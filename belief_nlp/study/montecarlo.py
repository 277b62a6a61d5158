"""Monte-Carlo safety: how often the paper's robot actually fails along a path.

The simulated system is the one the smoother plans for (paper eq. 2):

* the true state starts at x_0 ~ N(x0, P0); the estimate starts at x0;
* transition k applies the control u_k = xbar_k - xhat_{k-1} (the path's
  feed-forward step, corrected by the estimate so that the predicted estimate
  is the planned mean -- the premise of the belief path) and the state moves
  continuously, x(s) = x_{k-1} + s u_k + B(s), s in [0, 1], with B a
  Brownian motion of covariance W_k per step (the path's own transition
  noise); each transition is sampled at ``substeps`` points;
* after the transition a measurement realises the planned information S_k:
  y_k = C_k x_k + v_k with C_k^T C_k = S_k and v_k ~ N(0, I), and the
  Kalman filter updates xhat_k = xbar_k + P_k C_k^T (y_k - C_k xbar_k).
  The estimation error then has the planned covariance P_k.

A run fails when a sampled state lies inside an obstacle or outside the
domain during any transition, or when x_K ends outside the target. The
failure rate is reported with a Clopper--Pearson interval next to the
nominal rate 1 - confidence of a single confidence ellipse. ``control=
"open_loop"`` applies the planned steps xbar_k - xbar_{k-1} without
correction instead (sensing then does not steer the robot).

Everything is vectorised over runs and substeps; the loop runs over the K
transitions only (10,000 runs of a K = 20 path take well under a second,
``benchmarks/bench_study.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ValidationError
from ..path import BeliefPath
from ..scenario import Scenario, load_scenario

__all__ = ["MonteCarloResult", "simulate", "clopper_pearson"]


def clopper_pearson(failures: int, runs: int, level: float = 0.95) -> tuple[float, float]:
    """Exact (Clopper--Pearson) two-sided ``level`` interval of a binomial rate."""
    from scipy.stats import beta

    if runs <= 0:
        return 0.0, 1.0
    a = 1.0 - level
    lo = 0.0 if failures == 0 else float(beta.ppf(a / 2, failures, runs - failures + 1))
    hi = 1.0 if failures == runs else float(beta.ppf(1 - a / 2, failures + 1, runs - failures))
    return lo, hi


@dataclass(frozen=True)
class MonteCarloResult:
    """Outcome of :func:`simulate`.

    Attributes
    ----------
    runs, failures : int
        Runs simulated, runs that failed.
    rate : float
        failures / runs.
    ci_low, ci_high : float
        Clopper--Pearson interval of the rate at ``level``.
    level : float
        Confidence level of the interval.
    collisions, exits, misses : int
        Runs that touched an obstacle, left the domain, ended outside the
        target (a run may count in several).
    hazard_runs, step_hazard_runs : int
        Runs inside some hazard (obstacle or outside the domain) at any
        sampled instant, and at one of the K + 1 step times: the events that
        :class:`~belief_nlp.risk.RiskBound`'s ``continuous`` and ``step_time``
        bound.
    nominal_rate : float
        1 - confidence of one confidence ellipse (the paper's per-ellipse
        chance constraint), for comparison.
    substeps : int
        Samples per transition.
    control : str
        ``"feedback"`` or ``"open_loop"``, as given to :func:`simulate`.
    """

    runs: int
    failures: int
    rate: float
    ci_low: float
    ci_high: float
    level: float
    collisions: int
    exits: int
    misses: int
    nominal_rate: float
    substeps: int
    control: str
    hazard_runs: int = 0
    step_hazard_runs: int = 0

    def summary(self) -> str:
        """One line: failed runs, the rate with its Clopper-Pearson interval, the
        nominal rate, and the failures by kind (collisions, domain exits, target misses)."""
        return (f"{self.failures}/{self.runs} runs failed: rate {self.rate:.4f} "
                f"[{self.ci_low:.4f}, {self.ci_high:.4f}] ({self.level:.0%} Clopper-Pearson); nominal "
                f"{self.nominal_rate:.4f} per ellipse; collisions {self.collisions}, domain exits {self.exits}, "
                f"target misses {self.misses}")


def _sqrt_psd(M: np.ndarray) -> np.ndarray:
    """A factor L with L L^T = M for a (semi)definite M (eigen-based: P0 may be singular)."""
    w, V = np.linalg.eigh(0.5 * (M + M.T))
    return V * np.sqrt(np.maximum(w, 0.0))


def _max_slack(c: np.ndarray, A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """max_f (a_f . y - b_f) for points given by their coordinate rows c (d, N).

    Element-wise passes over contiguous coordinate rows: with d = 2 or 3 and a
    handful of faces this beats BLAS (tiny inner dimension) and never builds
    the (N, F) matrix.
    """
    out = None
    for a_f, b_f in zip(A, b):
        v = a_f[0] * c[0] - b_f
        for i in range(1, len(a_f)):
            v += a_f[i] * c[i]
        out = v if out is None else np.maximum(out, v, out=out)
    return out


def _inside_any(c: np.ndarray, polys) -> np.ndarray:
    """Coordinate rows (d, N) -> whether each point lies in one of the polytopes (touching counts)."""
    hit = np.zeros(c.shape[1], dtype=bool)
    for p in polys:
        lo, hi = p.vertices.min(axis=0), p.vertices.max(axis=0)
        # only points in the polytope's bounding box need the face test
        box = (c[0] >= lo[0]) & (c[0] <= hi[0])
        for i in range(1, c.shape[0]):
            box &= (c[i] >= lo[i]) & (c[i] <= hi[i])
        near = np.flatnonzero(box)
        if near.size:
            hit[near[_max_slack(c[:, near], p.A, p.b) <= 0.0]] = True
    return hit


def _mix(L: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """L @ Z for a tiny (d, d) L and wide (d, N) Z, element-wise (see _max_slack)."""
    out = np.empty_like(Z)
    for i in range(L.shape[0]):
        out[i] = L[i, 0] * Z[0]
        for j in range(1, L.shape[1]):
            out[i] += L[i, j] * Z[j]
    return out


def simulate(scenario: Scenario | str, path: BeliefPath | object, runs: int = 10_000, substeps: int = 20,
             seed: int | None = 0, level: float = 0.95, control: str = "feedback") -> MonteCarloResult:
    """Simulate the robot along ``path`` ``runs`` times and count failures (module docstring).

    Parameters
    ----------
    scenario : Scenario or built-in name / file.
    path : a BeliefPath, or a result with ``.path`` (PlanResult, SmoothResult).
    runs : number of simulated runs (>= 1).
    substeps : samples per transition (s = 1/n, ..., 1; s = 0 is the previous end).
    seed : seed of numpy's Generator (same seed, same result).
    level : level of the Clopper--Pearson interval.
    control : "feedback" (default, the belief path's premise) or "open_loop".
    """
    sc = load_scenario(scenario) if isinstance(scenario, str) else scenario
    path = getattr(path, "path", path)
    if not isinstance(path, BeliefPath):
        raise ValidationError("path", f"must be a BeliefPath or hold one in .path, got {type(path).__name__}")
    if path.dim != sc.dim:
        raise ValidationError("path", f"path is {path.dim}-D but the scenario is {sc.dim}-D")
    for name, v, lo in (("runs", runs, 1), ("substeps", substeps, 1)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise ValidationError(name, f"must be an integer >= {lo}, got {v!r:.40}")
    if control not in ("feedback", "open_loop"):
        raise ValidationError("control", f"must be 'feedback' or 'open_loop', got {control!r}")
    if not 0 < level < 1:
        raise ValidationError("level", f"must lie in (0, 1), got {level!r}")
    rng = np.random.default_rng(seed)
    R, n, d, K = int(runs), int(substeps), path.dim, path.K
    xbar = path.x
    obstacles = list(sc.obstacles)
    Ad, bd = sc.domain.A, sc.domain.b
    noise = path.P_prior[1:] - path.P[:-1]               # (K, d, d): the path's own W_k

    # states as coordinate rows (d, R): every pass below runs over contiguous memory
    x = xbar[0][:, None] + _mix(_sqrt_psd(path.P[0]), rng.standard_normal((d, R)))
    xhat = np.repeat(xbar[0][:, None], R, axis=1)
    exited = _max_slack(x, Ad, bd) > 0.0
    collided = _inside_any(x, obstacles)
    at_step = exited | collided                               # inside a hazard at a step time (t_0 here)
    s = np.arange(1, n + 1) / n
    for k in range(1, K + 1):
        u = (xbar[k][:, None] - xhat) if control == "feedback" else np.repeat((xbar[k] - xbar[k - 1])[:, None], R, 1)
        # Brownian path on the grid: independent increments of covariance W_k / n
        dB = _mix(_sqrt_psd(noise[k - 1]) / np.sqrt(n), rng.standard_normal((d, R * n))).reshape(d, R, n)
        pts = x[:, :, None] + s * u[:, :, None] + np.cumsum(dB, axis=2)      # (d, R, n)
        flat = pts.reshape(d, R * n)
        exited |= np.any((_max_slack(flat, Ad, bd) > 0.0).reshape(R, n), axis=1)
        collided |= np.any(_inside_any(flat, obstacles).reshape(R, n), axis=1)
        x = np.ascontiguousarray(pts[:, :, -1])
        at_step |= (_max_slack(x, Ad, bd) > 0.0) | _inside_any(x, obstacles)
        # measurement realising S_k: only the directions S_k informs are measured
        w, V = np.linalg.eigh(0.5 * (path.S[k] + path.S[k].T))
        keep = w > 1e-12 * max(1.0, float(np.max(np.abs(w))))
        C = (V[:, keep] * np.sqrt(w[keep])).T                     # (m, d), C^T C = S_k
        xpred = np.repeat(xbar[k][:, None], R, 1) if control == "feedback" else xhat + u
        if C.shape[0]:
            innovation = C @ (x - xpred) + rng.standard_normal((C.shape[0], R))
            xhat = xpred + (path.P[k] @ C.T) @ innovation          # Kalman gain with unit measurement noise
        else:
            xhat = xpred
    missed = _max_slack(x, sc.target.A, sc.target.b) > 0.0
    failed = collided | exited | missed
    f = int(failed.sum())
    lo, hi = clopper_pearson(f, R, level)
    if sc.confidence is not None:
        nominal = 1.0 - float(sc.confidence)
    else:
        from scipy.stats import chi2

        nominal = float(chi2.sf(sc.chi2, sc.dim))
    return MonteCarloResult(runs=R, failures=f, rate=f / R, ci_low=lo, ci_high=hi, level=level,
                            collisions=int(collided.sum()), exits=int(exited.sum()), misses=int(missed.sum()),
                            nominal_rate=nominal, substeps=n, control=control,
                            hazard_runs=int((collided | exited).sum()), step_hazard_runs=int(at_step.sum()))
