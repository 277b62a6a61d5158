"""Independent verification of a belief path against a scenario.

This module deliberately shares no distance code with :mod:`belief_nlp.geometry`:

* transitions are checked by dense sampling of s in [0, 1] (plus a refined
  grid around the worst sample), each sample checked exactly;
* 2-D polygons: whitened vertices, point-to-segment distances and a winding
  test; half-spaces: closed form; other polytopes: the least-distance problem
  solved by non-negative least squares (Lawson & Hanson's LDP via
  ``scipy.optimize.nnls``);
* target containment by the support function from an eigendecomposition.

The report's certified risk bounds (:mod:`belief_nlp.risk`) are the one
part computed from the exact geometry: they need the rigorous lower bound
on each pair's clearance, which sampling cannot give.

Sampling can only overestimate the minimum over s, so the refinement grid and
the tolerance below matter; the exact minimisation lives in geometry.py and
tests compare the two.

Every comparison is written so that NaN fails it (``not margin >= -tol``,
never ``margin < -tol``): a value that cannot be computed is a problem,
never a pass. A path with non-finite entries, or entries too large to be
squared safely (> 1e100), is reported unsafe without being measured.
"""

from __future__ import annotations

import numbers
import os
from dataclasses import dataclass, field, replace

import numpy as np

from ._limits import MAX_VERIFY_SAMPLES
from .errors import ValidationError
from .path import BeliefPath, result_path
from ._verify_distances import _chol2, _psd_part, _sqdist, _support
from ._verify_kalman import kalman_checks
from .polytope import Polytope
from .risk import RiskBound, path_risk
from .scenario import Scenario, load_scenario

# Path entries beyond this are not measured (their squares and products
# would overflow); the path is reported unsafe instead.
_MAX_CHECKABLE = 1e100

__all__ = ["verify", "VerificationReport"]


@dataclass
class VerificationReport:
    """Outcome of :func:`verify`; true in a boolean context when the path is safe.

    Margins are "squared Mahalanobis distance minus chi2" (>= 0 is safe)
    unless stated otherwise.

    Attributes
    ----------
    safe : bool
        Every check passed within ``tol``.
    min_margin : float
        Smallest safety margin over all transitions, hazards and target faces
        (target faces converted to the same unit).
    worst : str
        Human-readable name of the worst offender.
    transition_margins : ndarray, shape (K, J)
        Minimum over the sampled s, per transition and hazard (obstacles
        first, then domain walls; names in ``hazard_names``).
    hazard_names : list of str
        Names of the J hazards, in the columns' order.
    target_margins_m : ndarray, shape (N,)
        b_n - a_n^T x_K - sqrt(chi2 a_n^T P_K a_n) per target face, metres.
    kalman_residual : ndarray, shape (K,)
        Relative error of P_k against (P_prior_k^-1 + S_k)^-1.
    sensing_min_eig : ndarray, shape (K,)
        Smallest eigenvalue of S_k relative to its norm.
    noise_residual : ndarray, shape (K,)
        Relative error of P_prior_k - P_{k-1} against the scenario's noise model.
    start_residual : float
        Relative error of (x_0, P_0) against the scenario's start.
    tol : float
        The tolerance the margins were judged with (margins >= -tol * chi2 pass).
    problems : list of str
        The failed checks, in words.
    proof : str
        What decided the transitions: ``"sampling"`` (dense sampling of s,
        refined around the worst sample: a second opinion), or
        ``"certificates+sampling"`` when Theorem-1 certificates were given
        and prove every pair in closed form (then the sampling must agree too).
    certificate_margins : ndarray, shape (K, J), or None
        min(f_0(lam), f_1(lam)) - chi2 of the given certificates (a rigorous
        lower bound on the clearance), or None.
    risk : RiskBound or None
        Certified end-to-end collision-probability bounds of the path
        (:mod:`belief_nlp.risk`: per pair, Boole sums at the step times and
        in continuous time, and what they bound); None for a path that
        cannot be measured.
    """

    safe: bool
    min_margin: float
    worst: str
    transition_margins: np.ndarray
    hazard_names: list[str]
    target_margins_m: np.ndarray
    kalman_residual: np.ndarray
    sensing_min_eig: np.ndarray
    noise_residual: np.ndarray
    start_residual: float
    tol: float
    problems: list[str] = field(default_factory=list)
    proof: str = "sampling"
    certificate_margins: np.ndarray | None = None
    risk: RiskBound | None = None

    @property
    def risk_bound(self) -> float:
        """The certified bound on the probability of a collision at the step
        times (``risk.step_time``; NaN when the path cannot be measured)."""
        return float("nan") if self.risk is None else self.risk.step_time

    def __post_init__(self) -> None:
        # Read-only copies, like the path's arrays: a report cannot be edited
        # into saying something else.
        for name in ("transition_margins", "target_margins_m", "kalman_residual", "sensing_min_eig",
                     "noise_residual"):
            arr = np.array(getattr(self, name), dtype=float)
            arr.flags.writeable = False
            setattr(self, name, arr)

    def __bool__(self) -> bool:
        return self.safe

    def __repr__(self) -> str:
        shown = "; ".join(p[:100] for p in self.problems[:3])
        more = f" (+{len(self.problems) - 3} more)" if len(self.problems) > 3 else ""
        return (f"VerificationReport(safe={self.safe}, min_margin={self.min_margin:.4g}, worst={self.worst!r}, "
                f"problems={len(self.problems)}{': ' + shown + more if shown else ''})")

    def summary(self) -> str:
        """SAFE or UNSAFE with the smallest margin and the worst offender, then one line per problem.

        Returns
        -------
        str
            Lines separated by newlines.
        """
        head = "SAFE" if self.safe else "UNSAFE"
        lines = [f"{head}: min margin {self.min_margin:.4g} (worst: {self.worst})"]
        if self.risk is not None:
            lines.append(f"  {self.risk.summary()}")
        lines += [f"  - {p}" for p in self.problems]
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """The verdict as JSON-ready data (what results store as ``verification``).

        Returns
        -------
        dict
            ``safe``, ``min_margin``, ``worst``, ``problems``, ``proof``, and
            the extremes ``max_kalman_residual``, ``min_target_margin_m`` and
            ``min_certificate_margin`` (None without certificates), and the
            certified step-time risk bound ``risk_step_time`` (the
            continuous-time bound, ~0.5 s to compute, is ``risk.continuous``);
            the per-transition arrays are left out.
        """
        return {
            "safe": self.safe,
            "min_margin": self.min_margin,
            "worst": self.worst,
            "problems": list(self.problems),
            "max_kalman_residual": float(np.max(self.kalman_residual, initial=0.0)),
            "min_target_margin_m": float(np.min(self.target_margins_m, initial=np.inf)),
            "proof": self.proof,
            "min_certificate_margin": (None if self.certificate_margins is None
                                       else float(np.min(self.certificate_margins, initial=np.inf))),
            "risk_step_time": None if self.risk is None else self.risk.step_time,
        }


# ------------------------------------------------------------- arguments
def _as_scenario(scenario: object) -> tuple[Scenario, bool]:
    """(scenario, given by name?) from a Scenario, a built-in name or a scenario file."""
    if isinstance(scenario, Scenario):
        return scenario, False
    if isinstance(scenario, (str, os.PathLike)):
        return load_scenario(scenario), True
    raise ValidationError("scenario", f"must be a Scenario, a built-in name or a scenario file, "
                                      f"got {type(scenario).__name__}")


def _as_path(path: object) -> BeliefPath:
    """A BeliefPath, or the ``.path`` of a result (PlanResult, SmoothResult, ...)."""
    if isinstance(path, BeliefPath):
        return path
    inner = result_path(path)
    if inner is not None:
        return inner
    raise ValidationError("path", f"must be a BeliefPath or a result with a .path, got {type(path).__name__}")


def _sample_count(name: str, value: object) -> int:
    if (not isinstance(value, (numbers.Integral, np.integer)) or isinstance(value, (bool, np.bool_))
            or not 2 <= int(value) <= MAX_VERIFY_SAMPLES):
        raise ValidationError(name, f"must be an integer from 2 to {MAX_VERIFY_SAMPLES}, got {value!r:.40}")
    return int(value)


def _tolerance(value: object) -> float:
    try:
        ok = isinstance(value, (numbers.Real, np.floating, np.integer)) and not isinstance(value, (bool, np.bool_))
        tol = float(value) if ok else float("nan")
    except OverflowError:
        tol = float("nan")
    if not 0.0 <= tol < 1.0:  # also False for NaN
        raise ValidationError("tol", f"must be a finite number with 0 <= tol < 1 (a fraction of chi2), "
                                     f"got {value!r:.40}")
    return tol


def _unmeasured_report(path: BeliefPath, names: list[str], tol: float, problems: list[str]) -> VerificationReport:
    """The report for a path that cannot be measured: unsafe, every margin NaN."""
    K = path.K
    nan = np.full(K, np.nan)
    return VerificationReport(
        safe=False, min_margin=-np.inf, worst=problems[0], transition_margins=np.full((K, len(names)), np.nan),
        hazard_names=names, target_margins_m=np.full(0, np.nan), kalman_residual=nan, sensing_min_eig=nan,
        noise_residual=nan, start_residual=np.nan, tol=tol, problems=problems)


# ------------------------------------------------------------ certificates
def _certificate_margins(scenario: Scenario, path: BeliefPath, lam: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """min(f_0(lam), f_1(lam)) - chi2 per transition and hazard, closed form:
    f_s(lam) = -v^T P(s) v + 2 lam^T (A x(s) - b), v = A^T lam, at s = 0 (P_{k-1})
    and s = 1 (P_{k-1} + W_k). For lam >= 0 a lower bound on min_s dist2 (Theorem 1)."""
    K = path.K
    out = np.empty((K, len(scenario.hazards)))
    P0 = path.P[:-1]
    P1 = P0 + path.transition_noise
    for j, h in enumerate(scenario.hazards):
        lj = lam[:, j, : h.n_faces]                                   # (K, f)
        v = lj @ h.A                                                  # (K, d)
        f0 = -np.einsum("kd,kde,ke->k", v, P0, v) + 2 * np.einsum("kf,kf->k", lj, path.x[:-1] @ h.A.T - h.b)
        f1 = -np.einsum("kd,kde,ke->k", v, P1, v) + 2 * np.einsum("kf,kf->k", lj, path.x[1:] @ h.A.T - h.b)
        out[:, j] = np.minimum(f0, f1) - levels[:, j]
    return out


def _with_certificates(report: VerificationReport, scenario: Scenario, path: BeliefPath,
                       certificates, levels: np.ndarray) -> VerificationReport:
    """The report with the closed-form certificate check added."""
    lam = np.asarray(certificates, dtype=float)
    F = max(h.n_faces for h in scenario.hazards)
    if lam.ndim != 3 or lam.shape[:2] != (path.K, len(scenario.hazards)) or lam.shape[2] < F:
        raise ValidationError("certificates", f"must be (K, J, F) = ({path.K}, {len(scenario.hazards)}, >= {F}), "
                                              f"got {lam.shape}")
    problems = list(report.problems)
    if not np.all(np.isfinite(lam)) or np.any(lam < 0):
        problems.append("certificates must be finite and >= 0 (Theorem 1 holds only for lam >= 0)")
        cm = np.full((path.K, len(scenario.hazards)), np.nan)
    else:
        cm = _certificate_margins(scenario, path, lam, levels)
        for k, j in np.argwhere(~(cm >= 0))[:20]:
            problems.append(f"transition {k + 1} vs {report.hazard_names[j]}: the certificate does not prove "
                            f"clearance (margin {cm[k, j]:.3g})")
    proven = not any("certificate" in p for p in problems)
    return replace(report, safe=not problems, problems=problems, certificate_margins=cm,
                   proof="certificates+sampling" if proven else "sampling")


# ------------------------------------------------------------------ verify
def verify(scenario: Scenario | str | os.PathLike, path: BeliefPath | object, n_samples: int = 101,
           n_refine: int = 41, tol: float = 1e-6, certificates: np.ndarray | None = None,
           levels: float | np.ndarray | None = None, budget: float | None = None,
           risk_kind: str | None = None) -> VerificationReport:
    """Check a belief path for safety and consistency, independently of the solvers.

    Every transition is checked against every hazard by dense sampling of
    the transition parameter s (refined around the worst sample), the final
    ellipse against the target, and the covariances against the Kalman
    recursion, the noise model and the start. A margin that cannot be
    computed (NaN) is a failure, never a pass; a path with non-finite
    entries is reported unsafe.

    Parameters
    ----------
    scenario : Scenario, str or os.PathLike
        The scenario, a built-in name or a scenario file.
    path : BeliefPath or result
        A path, or a result holding one in ``.path``
        (:class:`~belief_nlp.PlanResult`, :class:`~belief_nlp.SmoothResult`).
    n_samples : int, optional
        Samples of s in [0, 1] per transition (endpoints included), from 2 to
        10001 (``belief_nlp._limits.MAX_VERIFY_SAMPLES``); default 101.
    n_refine : int, optional
        Extra samples in the interval on each side of the worst sample, same
        range; default 41.
    tol : float, optional
        Margins >= -tol * chi2 count as clear; 0 <= tol < 1 (default 1e-6).
        Relative residuals of the Kalman recursion and of the noise model
        must be <= 1e-6.
    certificates : ndarray, shape (K, J, F), optional
        Theorem-1 certificates in 1/m, hazards in ``scenario.hazards``
        order, faces padded with zeros (as ``SmoothResult.certificates``;
        taken from ``path`` when it is a result that carries them). Each
        must be >= 0 and prove its pair in closed form, min(f_0, f_1) >=
        chi2 (docs/safety.md); otherwise the path is not called safe.
    levels : float or ndarray, shape (K, J), optional
        The collision level of every transition-hazard pair (a path smoothed
        under a risk budget has its own per pair, ``SmoothResult.risk.levels``);
        None: the scenario's chi2 (transition 1 at ``scenario.chi2_start``
        when the scenario holds its start to a ``start_confidence``), or --
        for a result smoothed under a risk budget -- its ``risk.levels``.
        The target is always judged at the scenario's own chi2.
    budget : float, optional
        An end-to-end collision budget: the path is safe only when its
        certified bound of kind ``risk_kind`` is at most ``budget``; None
        for a result smoothed under a budget: its ``risk.budget``.
    risk_kind : {"steps", "continuous"}, optional
        Which bound ``budget`` limits: the step-time bound
        (``report.risk.step_time``, the default) or the continuous-time one
        (``report.risk.continuous``); for a result smoothed under a budget,
        its ``risk.kind``.

    Returns
    -------
    VerificationReport
        ``safe`` and the margins; true in a boolean context when safe.

    Raises
    ------
    ValidationError
        For bad arguments, naming the argument.
    ScenarioFileError
        When ``scenario`` names a file that cannot be read.
    """
    scenario, by_name = _as_scenario(scenario)
    if certificates is None:
        certificates = getattr(path, "certificates", None)
    allocation = getattr(path, "risk", None) if not isinstance(path, BeliefPath) else None
    if allocation is not None and hasattr(allocation, "levels"):
        # a result smoothed under a risk budget: judged at its own levels, under its own
        # budget unless another is given (verify(sc, res, budget=0.05) judged it at chi2)
        levels = allocation.levels if levels is None else levels
        budget = allocation.budget if budget is None else budget
        risk_kind = risk_kind or getattr(allocation, "kind", None)
    path = _as_path(path)
    n_samples = _sample_count("n_samples", n_samples)
    n_refine = _sample_count("n_refine", n_refine)
    tol = _tolerance(tol)
    if path.dim != scenario.dim:
        # a named scenario that does not fit the path is the argument at fault
        raise ValidationError("scenario" if by_name else "path.x",
                              f"path is {path.dim}-D but the scenario is {scenario.dim}-D")
    hazards = list(scenario.hazards)
    names = [h.name for h in hazards]
    levels = _levels(levels, path.K, len(hazards), scenario)
    from .allocation import RISK_KINDS, RiskBudget

    kind = "steps" if risk_kind is None else str(risk_kind).lower()
    if kind not in RISK_KINDS:
        raise ValidationError("risk_kind", f"must be one of {RISK_KINDS}, got {risk_kind!r:.40}")
    if budget is not None:
        budget = RiskBudget(budget).budget
    unmeasurable = [f"path.{f} contains NaN or infinite values" for f in ("x", "P", "P_prior", "S")
                    if not np.all(np.isfinite(getattr(path, f)))]
    unmeasurable += [f"path.{f} has entries beyond {_MAX_CHECKABLE:g}; not checked" for f in ("x", "P", "P_prior", "S")
                     if np.all(np.isfinite(getattr(path, f))) and np.max(np.abs(getattr(path, f))) > _MAX_CHECKABLE]
    if unmeasurable:
        return _unmeasured_report(path, names, tol, unmeasurable)
    with np.errstate(all="ignore"):  # overflow gives NaN margins, which _measure reports
        try:
            report = _measure(scenario, path, hazards, names, n_samples, n_refine, tol, levels)
            if certificates is not None:
                report = _with_certificates(report, scenario, path, certificates, levels)
            report = replace(report, risk=path_risk(scenario, path, certificates))
            if budget is not None:
                bound = report.risk.continuous if kind == "continuous" else report.risk.step_time
                if not bound <= budget * (1 + 1e-9):
                    what = "continuous-time" if kind == "continuous" else "step-time"
                    report = replace(report, safe=False, problems=report.problems + [
                        f"the certified {what} collision bound {bound:.4g} exceeds the budget {budget:.4g}"])
            return report
        except np.linalg.LinAlgError as exc:  # an eigen-solver gave up: nothing is proven
            return _unmeasured_report(path, names, tol, [f"numerical failure while measuring the path: {exc}"])


def _levels(levels: object, K: int, J: int, scenario: Scenario) -> np.ndarray:
    """(K, J) collision levels from None (the scenario's: chi2, transition 1
    at its start level), a number or an array."""
    if levels is None:
        lv = np.full((K, J), float(scenario.chi2))
        lv[0] = scenario.chi2_start
        return lv
    try:
        lv = np.broadcast_to(np.asarray(levels, dtype=float), (K, J)).copy()
    except (ValueError, TypeError):
        raise ValidationError("levels", f"must be a number or a ({K}, {J}) array of levels") from None
    if not np.all(np.isfinite(lv)) or np.any(lv <= 0):
        raise ValidationError("levels", "every level must be a finite number > 0")
    return lv


def _measure(scenario: Scenario, path: BeliefPath, hazards: list[Polytope], names: list[str], n_samples: int,
             n_refine: int, tol: float, levels: np.ndarray) -> VerificationReport:
    problems: list[str] = []
    # Covariances must be symmetric PSD for the ellipses to mean anything;
    # report it, and sample with the nearest PSD matrices so the rest of the
    # report is still computed.
    P_post, P_bad = _psd_part(path.P)
    _, Pp_bad = _psd_part(path.P_prior)
    for k in np.nonzero(P_bad)[0]:
        problems.append(f"P_{k} is not a covariance (not symmetric positive semidefinite)")
    for k in np.nonzero(Pp_bad)[0]:
        problems.append(f"P_prior_{k} is not a covariance (not symmetric positive semidefinite)")
    chi2 = scenario.chi2
    K = path.K
    Wk = path.transition_noise
    s = np.linspace(0.0, 1.0, n_samples)
    margins = np.empty((K, len(hazards)))
    # the samples are the same for every hazard: their covariances' factor too (2-D polygons)
    xs = (path.x[:-1, None, :] + s[None, :, None] * np.diff(path.x, axis=0)[:, None, :]).reshape(-1, scenario.dim)
    Ps = (P_post[:-1, None] + s[None, :, None, None] * Wk[:, None]).reshape(-1, scenario.dim, scenario.dim)
    polygons = scenario.dim == 2 and any(h.n_faces > 1 and h.vertices is not None for h in hazards)
    chol = _chol2(Ps) if polygons else None
    for j, h in enumerate(hazards):
        vals = _sqdist(xs, Ps, h, chol=chol)
        vals = vals.reshape(K, n_samples)
        # refine around the worst sample of each transition (a NaN sample counts as the worst)
        i = np.argmin(np.where(np.isnan(vals), -np.inf, vals), axis=1)
        lo = s[np.maximum(i - 1, 0)]
        hi = s[np.minimum(i + 1, n_samples - 1)]
        r = lo[:, None] + np.linspace(0, 1, n_refine)[None, :] * (hi - lo)[:, None]
        xr = path.x[:-1, None, :] + r[..., None] * np.diff(path.x, axis=0)[:, None, :]
        Pr = P_post[:-1, None] + r[..., None, None] * Wk[:, None]
        vr = _sqdist(xr.reshape(-1, scenario.dim), Pr.reshape(-1, scenario.dim, scenario.dim), h)
        # np.minimum and min() propagate NaN: an undecidable sample keeps the pair undecided
        margins[:, j] = np.minimum(vals.min(axis=1), vr.reshape(K, n_refine).min(axis=1)) - levels[:, j]

    atol = tol * chi2
    # target containment of the final posterior
    T = scenario.target
    xK, PK = path.x[-1], P_post[-1]
    t_m = T.b - T.A @ xK - np.sqrt(chi2) * _support(PK, T.A)
    aPa = np.einsum("fi,ij,fj->f", T.A, PK, T.A) + 1e-30
    slack = T.b - T.A @ xK
    t_maha = np.sign(slack) * slack**2 / aPa - chi2
    # Kalman consistency and sensing
    kal, smin = kalman_checks(path)
    # noise model
    if path.noise == "per_step":
        W_model = np.broadcast_to(scenario.W, Wk.shape)
    else:
        lengths = np.linalg.norm(np.diff(path.x, axis=0), axis=1)
        W_model = lengths[:, None, None] * scenario.W_rate[None]
    noise_res = np.linalg.norm(Wk - W_model, axis=(1, 2)) / np.maximum(np.linalg.norm(W_model, axis=(1, 2)), 1e-300)
    start_res = float(max(np.linalg.norm(path.x[0] - scenario.x0) / (1 + np.linalg.norm(scenario.x0)),
                          np.linalg.norm(path.P[0] - scenario.P0) / max(np.linalg.norm(scenario.P0), 1e-300)
                          if np.linalg.norm(scenario.P0) > 0 else np.linalg.norm(path.P[0])))

    # The worst pair and the minimum treat NaN as -inf: undecided is worst.
    ranked = np.where(np.isnan(margins), -np.inf, margins)
    worst_idx = np.unravel_index(np.argmin(ranked), ranked.shape) if ranked.size else None
    min_trans = float(ranked[worst_idx]) if worst_idx is not None else np.inf
    t_ranked = np.where(np.isnan(t_maha), -np.inf, t_maha)
    min_target = float(np.min(t_ranked))
    if min_trans <= min_target:
        min_margin = min_trans
        worst = f"transition {worst_idx[0] + 1} vs {names[worst_idx[1]]}"
    else:
        min_margin = min_target
        worst = f"target face {int(np.argmin(t_ranked))} (final ellipse containment)"
    # Each test is "not (good)", so that NaN counts as a failure.
    bad = np.argwhere(~(margins >= -tol * levels))
    for k, j in bad[:20]:
        if np.isnan(margins[k, j]):
            problems.append(f"transition {k + 1} vs {names[j]} cannot be decided (margin NaN)")
        else:
            problems.append(f"transition {k + 1} collides with {names[j]} (margin {margins[k, j]:.4g})")
    if len(bad) > 20:
        problems.append(f"... and {len(bad) - 20} more colliding transition/hazard pairs")
    for n_ in np.nonzero(~(t_maha >= -atol))[0]:
        problems.append(f"final ellipse leaves the target across face {n_} ({t_m[n_]:.3g} m)")
    for k in np.nonzero(~(kal <= 1e-6))[0]:
        problems.append(f"P_{k + 1} is not the Kalman update of P_prior_{k + 1} and S_{k + 1} (rel. err {kal[k]:.3g})")
    for k in np.nonzero(~(smin >= -1e-8))[0]:
        problems.append(f"S_{k + 1} is not positive semidefinite (min eig / norm {smin[k]:.3g})")
    for k in np.nonzero(~(noise_res <= 1e-6))[0]:
        problems.append(f"transition {k + 1} noise does not match the scenario's {path.noise} model (rel. err {noise_res[k]:.3g})")
    if not start_res <= 1e-9:
        problems.append(f"path does not start at the scenario's start belief (rel. err {start_res:.3g})")
    return VerificationReport(
        safe=not problems, min_margin=min_margin, worst=worst, transition_margins=margins,
        hazard_names=names, target_margins_m=t_m, kalman_residual=kal, sensing_min_eig=smin,
        noise_residual=noise_res, start_residual=start_res, tol=tol, problems=problems)
