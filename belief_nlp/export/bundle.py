"""Constraint bundles: the belief-space safety constraints of a scenario as
two stacked CasADi functions with their bounds, row names and scales.

A **stage bundle** holds the Theorem-1 transition constraints (C5) of one
step against *all* hazards (obstacles, then the domain walls, the order of
``scenario.hazards``) in ONE function::

    g = stage(x_prev, P_prev, x_next, W, lam, p)          lbg <= g <= ubg

* ``lam`` (J F): one certificate per hazard and face, hazard-major
  (``lam[j F + f]``); hazards are padded to the common face count F with the
  face ``0^T y <= 1`` (the whole space: the polytope is unchanged and a
  certificate on it only lowers the margin, so padding can never certify).
* ``p``: the obstacle data as a parameter vector (vec A row-major (J F d),
  b (J F), one confidence level per hazard (J)), so obstacles, walls and the
  levels can change at run time without exporting or compiling again
  (:meth:`SafetyBundle.params`); a stage of an MPC can take the smoother's
  risk allocation for its transition (``params(levels=result.risk.levels[k])``,
  :meth:`SafetyBundle.stage_params`).
* rows: per hazard j the start and end margins (``<name>_start``,
  ``<name>_end``; dimensionless, >= ``margin``), then every certificate
  (``<name>_lam_<f>`` >= 0). The certificate bounds are rows of ``g``, so
  an adapter that installs ``g`` with ``lbg`` cannot drop them: a belief
  whose mean lies inside an obstacle violates the bundle whatever the
  certificates (negative ones included).

A **terminal bundle** holds the target containment (C4) of the final belief
in the smooth squared form :func:`~belief_nlp.model.terms.target_margin_sq_cov`
(length^2; no square root, defined for every iterate, >= 0 exactly when the
90 % ellipse lies in the target): ``g = terminal(x, P, p_target)`` with
``p_target`` = (vec A_t row-major, b_t, chi2).

Both come from :mod:`belief_nlp.model.terms` (no second derivation) and in
two unit systems. **SI**: x, b in m, P, W in m^2, lam in 1/m. **Scaled**
(the model's internal units, docs/numerics.md): lengths divided by
sigma = sqrt(max eig W), so x' = x / sigma, P' = P / sigma^2, lam' = sigma
lam, S' = sigma^2 S; the margin rows are unit-free and equal in both, the
terminal rows are divided by sigma^2. ``bundle.factors`` gives each factor
(value in bundle units = factor * SI value). Solvers want the scaled form:
in SI, W ~ 2e-4 m^2 and P0 ~ 1e-9 m^2 put IPOPT's tolerances at the scale of
the data.

**Soft variants** (:meth:`SafetyBundle.soft`, :meth:`TerminalBundle.soft`)
take an extra input ``slack`` (one per margin row), add it to those rows,
ship ``slack >= 0`` rows, and output the penalty ``weight * sum(slack)``
(L1, exact for a large enough weight) or ``weight * sum(slack^2)`` (L2).
Certificate rows are never softened.

**SX and MX.** The functions are built from SX symbols. Called on SX (a
do-mpc or acados model) they inline into plain expressions; called on MX
(``casadi.Opti``, rockit) they become one call node per stage -- pass
``expand=True`` to the solver (or use ``bundle.function.expand()``) to get
SX speed, or ``bundle.function.map(N)`` to evaluate all stages at once.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any

import casadi as ca
import numpy as np

from ..errors import ValidationError
from ..model import terms
from ..scenario import Scenario, load_scenario
from .functions import _slug

__all__ = ["SafetyBundle", "TerminalBundle", "stage_bundle", "terminal_bundle", "scale_factors", "PAD_OFFSET"]

#: Lower bound of the terminal rows, in units of sigma^2 (the squared form's scale):
#: ~1e-5 sigma^2 = 2e-9 m^2 on paper-multi, a containment buffer of ~1e-7 m.
TARGET_MARGIN = 1e-5
#: Offset (m) of the padding face 0^T y <= PAD_OFFSET: any positive value is the whole space.
PAD_OFFSET = 1.0
_NORMS = ("l1", "l2")


def scale_factors(sigma: float) -> dict[str, float]:
    """Factor per quantity: value in scaled units = factor * SI value."""
    s = float(sigma)
    return {"x": 1 / s, "b": 1 / s, "P": 1 / s**2, "W": 1 / s**2, "S": s**2, "lam": s,
            "margin": 1.0, "target": 1 / s**2}


def _sigma(sc: Scenario) -> float:
    return float(np.sqrt(np.max(np.linalg.eigvalsh(np.asarray(sc.W, float)))))


def _scenario(scenario: Scenario | str) -> Scenario:
    return load_scenario(scenario) if isinstance(scenario, str) else scenario


def _pick_rows(p, offset: int, n: int, d: int):
    """Rows offset..offset+n of a row-major (n, d) matrix stored in p."""
    return ca.vertcat(*[p[offset + r * d: offset + (r + 1) * d].T for r in range(n)])


def _soft_rows(rows: ca.SX, slack: ca.SX, weight: float, norm: str) -> tuple[ca.SX, ca.SX]:
    pen = weight * (ca.sum1(slack) if norm == "l1" else ca.sumsqr(slack))
    return rows + slack, pen


@lru_cache(maxsize=32)
def _stage_function(d: int, J: int, F: int, soft: tuple | None, name: str) -> ca.Function:
    x0, P0 = ca.SX.sym("x_prev", d), ca.SX.sym("P_prev", d, d)
    x1, W = ca.SX.sym("x_next", d), ca.SX.sym("W", d, d)
    lam = ca.SX.sym("lam", J * F)
    p = ca.SX.sym("p", J * F * d + J * F + J)
    margins = []
    for j in range(J):
        chi2 = p[J * F * d + J * F + j]
        A = _pick_rows(p, j * F * d, F, d)
        b = p[J * F * d + j * F: J * F * d + (j + 1) * F]
        lj = lam[j * F:(j + 1) * F]
        margins += [terms.collision_margin_cov(x0, P0, lj, A, b, chi2),
                    terms.collision_margin_cov(x1, terms.predict(P0, W), lj, A, b, chi2)]
    rows = ca.vertcat(*margins)
    ins, in_names = [x0, P0, x1, W, lam], ["x_prev", "P_prev", "x_next", "W", "lam"]
    if soft is None:
        return ca.Function(name, ins + [p], [ca.vertcat(rows, lam)], in_names + ["p"], ["g"])
    slack = ca.SX.sym("slack", 2 * J)
    rows, pen = _soft_rows(rows, slack, *soft)
    return ca.Function(name, ins + [slack, p], [ca.vertcat(rows, lam, slack), pen],
                       in_names + ["slack", "p"], ["g", "penalty"])


@lru_cache(maxsize=32)
def _terminal_function(d: int, N: int, soft: tuple | None, name: str) -> ca.Function:
    x, P = ca.SX.sym("x", d), ca.SX.sym("P", d, d)
    p = ca.SX.sym("p", N * d + N + 1)
    chi2 = p[-1]
    A = _pick_rows(p, 0, N, d)
    rows = ca.vertcat(*[terms.target_margin_sq_cov(x, P, A[n, :].T, p[N * d + n], chi2) for n in range(N)])
    if soft is None:
        return ca.Function(name, [x, P, p], [rows], ["x", "P", "p"], ["g"])
    slack = ca.SX.sym("slack", N)
    rows, pen = _soft_rows(rows, slack, *soft)
    return ca.Function(name, [x, P, slack, p], [ca.vertcat(rows, slack), pen], ["x", "P", "slack", "p"],
                       ["g", "penalty"])


def _check_soft(weight: Any, norm: str) -> tuple[float, str]:
    if norm not in _NORMS:
        raise ValidationError("norm", f"must be one of {_NORMS}, got {norm!r}")
    if not isinstance(weight, (int, float)) or not np.isfinite(weight) or weight <= 0:
        raise ValidationError("weight", f"must be a finite number > 0, got {weight!r}")
    return float(weight), norm


@dataclass(frozen=True)
class _Bundle:
    """What both bundles share: the function, its rows and its units."""

    function: ca.Function
    names: tuple[str, ...]
    lbg: np.ndarray
    ubg: np.ndarray
    nominal: np.ndarray          # a typical magnitude per row (for solver scaling)
    units: str                   # "SI" or "scaled"
    sigma: float                 # the scenario's sigma = sqrt(max eig W), metres
    d: int
    soft_penalty: tuple | None = None    # (weight, norm) of a soft variant
    _p: np.ndarray = field(default=None, repr=False)   # the scenario's parameters, bundle units

    @property
    def factors(self) -> dict[str, float]:
        """value in bundle units = factor * SI value (all 1 for an SI bundle)."""
        return scale_factors(self.sigma) if self.units == "scaled" else scale_factors(1.0)

    @property
    def n_rows(self) -> int:
        return len(self.names)

    @property
    def n_slack(self) -> int:
        return 0 if self.soft_penalty is None else int(self.function.size1_in("slack"))

    def _length(self) -> float:
        return self.factors["x"]


@dataclass(frozen=True)
class SafetyBundle(_Bundle):
    """Theorem-1 transition constraints of one step against all hazards (see the module doc).

    Attributes: ``function`` (x_prev, P_prev, x_next, W, lam[, slack], p) -> g[, penalty];
    ``names``, ``lbg``, ``ubg``, ``nominal`` per row; ``hazard_names``;
    ``J`` hazards padded to ``F`` faces; ``lam_lb`` (zeros, J F) -- the same bounds
    as the certificate rows, for tools that prefer variable bounds.
    """

    J: int = 0
    F: int = 0
    hazard_names: tuple[str, ...] = ()
    margin: float = 0.0

    @property
    def n_lam(self) -> int:
        """Number of certificate entries, J hazards times F faces."""
        return self.J * self.F

    @property
    def lam_lb(self) -> np.ndarray:
        """Lower bounds of the certificates: zeros, shape (J F,) (certificates are >= 0)."""
        return np.zeros(self.n_lam)

    def params(self, scenario: Scenario | str | None = None, levels: float | np.ndarray | None = None) -> np.ndarray:
        """The parameter vector p (bundle units) for ``scenario`` (default: the
        one the bundle was built for). A scenario with moved obstacles gives new
        values for the same function; it must have J hazards of at most F faces.
        ``levels``: the confidence level (squared radius) of each hazard, one
        number or (J,) (default: the scenario's chi2 for all)."""
        p = self._p.copy() if scenario is None else self._scenario_params(_scenario(scenario))
        if levels is not None:
            lv = np.asarray(levels, float)
            if lv.ndim > 1 or lv.size not in (1, self.J) or not np.all(np.isfinite(lv)) or np.any(lv <= 0):
                raise ValidationError("levels", f"must be one number or {self.J} finite numbers > 0")
            p[-self.J:] = lv
        return p

    def stage_params(self, levels: np.ndarray, scenario: Scenario | str | None = None) -> np.ndarray:
        """(n_p, K) parameter columns, stage k at ``levels[k]`` -- e.g. the
        smoother's allocation ``result.risk.levels`` (K, J) -- for an MPC whose
        stages each take their own p (:class:`~belief_nlp.export.OptiMPC` ``p``)."""
        lv = np.asarray(levels, float)
        if lv.ndim != 2 or lv.shape[1] != self.J:
            raise ValidationError("levels", f"must be (K, {self.J}) levels, got shape {lv.shape}")
        return np.column_stack([self.params(scenario, row) for row in lv])

    def _scenario_params(self, sc: Scenario) -> np.ndarray:
        hz = sc.hazards
        if len(hz) != self.J or max(h.n_faces for h in hz) > self.F or sc.dim != self.d:
            raise ValidationError("scenario", f"needs {self.J} hazards of at most {self.F} faces in {self.d}-D, "
                                              f"got {len(hz)} of up to {max(h.n_faces for h in hz)}")
        A = np.zeros((self.J, self.F, self.d))
        b = np.full((self.J, self.F), PAD_OFFSET)
        for j, h in enumerate(hz):
            A[j, :h.n_faces] = h.A
            b[j, :h.n_faces] = h.b
        return np.concatenate([A.ravel(), b.ravel() * self._length(), np.full(self.J, float(sc.chi2))])

    def __call__(self, x_prev, P_prev, x_next, W, lam, p=None, slack=None):
        """g (or (g, penalty) for a soft bundle) on numbers or symbols; p defaults to :meth:`params`."""
        p = self._p if p is None else p
        if self.soft_penalty is None:
            return self.function(x_prev, P_prev, x_next, W, lam, p)
        return self.function(x_prev, P_prev, x_next, W, lam, slack, p)

    def lam_matrix(self, lam: np.ndarray) -> np.ndarray:
        """A flat certificate vector (J F) as (J, F)."""
        return np.asarray(lam, float).reshape(self.J, self.F)

    def scaled(self) -> "SafetyBundle":
        """The same constraints in the model's scaled units (:attr:`factors`)."""
        return _make_stage(self, "scaled", self.soft_penalty)

    def soft(self, weight: float, norm: str = "l1") -> "SafetyBundle":
        """The soft variant: margin rows + slack >= lbg, slack >= 0, penalty
        ``weight * sum(slack)`` (l1) or ``weight * sum(slack^2)`` (l2)."""
        return _make_stage(self, self.units, _check_soft(weight, norm))


@dataclass(frozen=True)
class TerminalBundle(_Bundle):
    """Target containment of the final belief, squared form (see the module doc).

    ``function`` (x, P[, slack], p) -> g[, penalty]; rows ``target_face_<n>`` in
    length^2 of the bundle's units (m^2 SI, sigma^2 scaled), >= 0.
    """

    n_faces: int = 0

    def params(self, scenario: Scenario | str | None = None) -> np.ndarray:
        """p = (vec A_t, b_t, chi2) in bundle units for ``scenario`` (default: the bundle's)."""
        if scenario is None:
            return self._p.copy()
        sc = _scenario(scenario)
        if sc.target.n_faces != self.n_faces:
            raise ValidationError("scenario", f"the target must have {self.n_faces} faces, got {sc.target.n_faces}")
        return np.concatenate([sc.target.A.ravel(), sc.target.b * self._length(), [float(sc.chi2)]])

    def __call__(self, x, P, p=None, slack=None):
        p = self._p if p is None else p
        return self.function(x, P, p) if self.soft_penalty is None else self.function(x, P, slack, p)

    def scaled(self) -> "TerminalBundle":
        """The same constraints in the model's scaled units (as :meth:`SafetyBundle.scaled`)."""
        return _make_terminal(self, "scaled", self.soft_penalty)

    def soft(self, weight: float, norm: str = "l1") -> "TerminalBundle":
        """Soft variant (as :meth:`SafetyBundle.soft`)."""
        return _make_terminal(self, self.units, _check_soft(weight, norm))


def _suffix(units: str, soft: tuple | None) -> str:
    return ("_scaled" if units == "scaled" else "") + ("" if soft is None else f"_soft_{soft[1]}")


def _make_stage(base: SafetyBundle, units: str, soft: tuple | None) -> SafetyBundle:
    J, F, d = base.J, base.F, base.d
    fn = _stage_function(d, J, F, soft, "belief_safety_stage" + _suffix(units, soft))
    s = base.sigma if units == "scaled" else 1.0
    names = [f"{h}_{e}" for h in base.hazard_names for e in ("start", "end")]
    names += [f"{h}_lam_{f}" for h in base.hazard_names for f in range(F)]
    lb = [base.margin] * (2 * J) + [0.0] * (J * F)
    nominal = [max(1.0, float(lv)) for lv in base._p[-J:] for _ in range(2)] + [s / base.sigma] * (J * F)
    if soft is not None:
        names += [f"{h}_{e}_slack" for h in base.hazard_names for e in ("start", "end")]
        lb += [0.0] * (2 * J)
        nominal += [1.0] * (2 * J)
    out = replace(base, function=fn, names=tuple(names), lbg=np.array(lb), ubg=np.full(len(lb), np.inf),
                  nominal=np.array(nominal), units=units, soft_penalty=soft)
    p = base._p.copy()
    nb = J * F * d
    p[nb:nb + J * F] *= (1 / base.sigma if units == "scaled" else 1.0) / base._length()
    object.__setattr__(out, "_p", p)
    return out


def _make_terminal(base: TerminalBundle, units: str, soft: tuple | None) -> TerminalBundle:
    N, d = base.n_faces, base.d
    fn = _terminal_function(d, N, soft, "belief_target_terminal" + _suffix(units, soft))
    names = [f"target_face_{n}" for n in range(N)]
    nominal = [(base.sigma if units == "SI" else 1.0) ** 2] * N
    lb = [TARGET_MARGIN * nominal[0]] * N       # a hair inside, so rounding never lands outside
    if soft is not None:
        names += [f"target_face_{n}_slack" for n in range(N)]
        lb += [0.0] * N
        nominal += [nominal[0]] * N
    out = replace(base, function=fn, names=tuple(names), lbg=np.array(lb), ubg=np.full(len(lb), np.inf),
                  nominal=np.array(nominal), units=units, soft_penalty=soft)
    p = base._p.copy()
    p[N * d:N * d + N] *= (1 / base.sigma if units == "scaled" else 1.0) / base._length()
    object.__setattr__(out, "_p", p)
    return out


def stage_bundle(scenario: Scenario | str, scaled: bool = False, margin: float | None = None,
                 soft: tuple[float, str] | None = None) -> SafetyBundle:
    """The stage bundle of ``scenario`` (SI, or ``scaled=True``).

    ``margin``: lower bound of the margin rows (dimensionless, in units of
    the squared Mahalanobis distance; default 1e-6 chi2, so that solver
    rounding never meets an exactly active constraint). ``soft=(weight,
    norm)`` gives the soft variant directly.
    """
    sc = _scenario(scenario)
    hz = sc.hazards
    J, F, d = len(hz), max(h.n_faces for h in hz), sc.dim
    margin = 1e-6 * float(sc.chi2) if margin is None else float(margin)
    if not np.isfinite(margin) or margin < 0:
        raise ValidationError("margin", f"must be a finite number >= 0, got {margin!r}")
    seed = SafetyBundle(function=None, names=(), lbg=np.zeros(0), ubg=np.zeros(0), nominal=np.zeros(0),
                        units="SI", sigma=_sigma(sc), d=d, J=J, F=F,
                        hazard_names=tuple(_slug(h.name) for h in hz), margin=margin)
    object.__setattr__(seed, "_p", seed._scenario_params(sc))
    out = _make_stage(seed, "scaled" if scaled else "SI", None)
    return out if soft is None else out.soft(*soft)


def terminal_bundle(scenario: Scenario | str, scaled: bool = False,
                    soft: tuple[float, str] | None = None) -> TerminalBundle:
    """The terminal (target containment) bundle of ``scenario`` (SI, or ``scaled=True``)."""
    sc = _scenario(scenario)
    seed = TerminalBundle(function=None, names=(), lbg=np.zeros(0), ubg=np.zeros(0), nominal=np.zeros(0),
                          units="SI", sigma=_sigma(sc), d=sc.dim, n_faces=sc.target.n_faces)
    object.__setattr__(seed, "_p", seed.params(sc))
    out = _make_terminal(seed, "scaled" if scaled else "SI", None)
    return out if soft is None else out.soft(*soft)
