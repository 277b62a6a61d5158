"""Planner options: defaults, scenario defaults and validation, in one place.

Every option a user can pass to :func:`~belief_nlp.planner.plan` or
:class:`~belief_nlp.planner.IGRRTStar` is a field of :class:`PlannerOptions`.
:func:`resolve_options` merges (in increasing priority) the defaults below,
the scenario's ``[planner]`` table and the keyword arguments, then validates
everything; a bad value raises :class:`~belief_nlp.errors.ValidationError`
naming the option.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from .._limits import MAX_ALPHA, MAX_CHI2, MAX_PLANNER_NODES, MAX_VARIANCE
from ..errors import ValidationError

__all__ = ["PlannerOptions", "resolve_options", "METRICS", "NOISE_MODELS", "INFO_UNITS", "default_gamma",
           "PER_STEP_RADIUS_PER_ALPHA"]

METRICS = ("entropy", "wasserstein", "hellinger")
NOISE_MODELS = ("per_metre", "per_step")
INFO_UNITS = ("nats", "bits")
STEERING = ("geodesic", "linear")
BACKENDS = ("auto", "numpy", "numba")
#: radius_per_alpha under per-step noise unless given: one unsensed step costs
#: alpha/2 log det(I + W P^-1) whatever its length (0.35 alpha at P = 2 W), so
#: a fixed cap leaves no edge at alpha ~ 1 (tutorial, quad, cube3d: no path at
#: alpha = 1 with 0; the 2-D built-ins plan at 0.1, 0.5 and 1 with 1.2, the
#: value paper-multi was tuned with; the cost sums over the d directions, and
#: cube3d's file sets 2.4: docs/planner.md, "The cap in 3-D")
PER_STEP_RADIUS_PER_ALPHA = 1.2


@dataclass(frozen=True)
class PlannerOptions:
    """All IG-RRT* options (validated by :func:`resolve_options`).

    Attributes
    ----------
    n_nodes : nodes in the tree when the run stops (the root counts, nodes
        later removed by branch-and-bound count too), as in the authors' N.
    seed : seed of the numpy Generator (None: fresh entropy, not reproducible).
    alpha : information weight; None takes the scenario's.
    metric : information term of the edge cost. ``"entropy"``:
        1/2 (log det P_hat - log det P2) (the smoothing paper's D_info);
        ``"wasserstein"``: Bures/2-Wasserstein distance of the covariances
        (metres); ``"hellinger"``: Hellinger distance of the zero-mean
        Gaussians (dimensionless). As in the authors' IG-RRT*.
    info_unit : ``"nats"`` (natural log, the default) or ``"bits"`` (log 2,
        the authors' IG-RRT*); entropy metric only. bits = nats / ln 2.
    noise : ``"per_metre"``: P_hat = P + W_rate * ||dx|| (the authors'
        planner); ``"per_step"``: P_hat = P + W for every edge, whatever its
        length (the smoothing paper's model, one edge = one time step).
    time_limit : wall-clock limit in seconds, or None.
    branch_and_bound : prune nodes that cannot lead to a path cheaper than the
        best one found (cost-to-come + admissible cost-to-go bound > best).
    prune_every : run the pruning every this many nodes (authors: 10).
        Accepted for the authors' settings; every value gives the same tree,
        since between two improvements of the best cost a pruning pass finds
        nothing to drop (see :meth:`IGRRTStar.plan`), so the planner prunes
        when the best cost improves.
    eig_range : (low, high) range of the eigenvalues of sampled covariances,
        m^2 (authors: 1e-9 .. 1e-1).
    eig_ratio : largest ratio between the eigenvalues of one sample (authors:
        10); the first eigenvalue is log-uniform in ``eig_range``, the others
        within this factor of it.
    steering : how a sample farther than the radius from its nearest node is
        pulled in: ``"geodesic"`` (default; P moves from the node's predicted
        prior toward the sample's covariance along the matrix-geometric path,
        so the step is always lossless) or ``"linear"`` (the authors: x and P
        interpolated linearly).
    max_radius : cap of the rewiring radius (in cost units); scenario default.
    radius_per_alpha : the cap grows by this much per unit of alpha:
        cap = max_radius + radius_per_alpha * alpha. With per-step noise an
        edge's information cost, alpha/2 log det((P + W) P^-1), does not shrink
        with its length, so a cap fit for alpha = 0.1 finds no path at 1
        (paper-multi: 0.3 + 1.2 alpha plans both of the paper's settings).
        None (the default): :data:`PER_STEP_RADIUS_PER_ALPHA` with per-step
        noise, 0 with per-metre noise (whose information cost shrinks with
        the edge).
    gamma : radius constant: r_n = min(max_radius, gamma (log n / n)^(1/d)).
        None gives the authors' value 50 * gamma* (13.8 in 2-D).
    goal_bias : probability of drawing the sample's mean in the target
        (authors: 0; our default 0.05 finds first solutions sooner and, with
        geodesic steering, cheaper paths: see benchmarks/bench_planner.py).
    convergence_tol, convergence_window : stop once a solution exists and the
        best cost improved by at most ``convergence_tol`` (relative) over the
        last ``convergence_window`` nodes. None: off.
    max_attempts : cap on sampling attempts (samples that get no node count as
        attempts); None: 200 * n_nodes + 1000. Guards against endless loops.
    safety_margin : relative margin on chi2 for every clearance decision
        (edges, sample ellipses, target containment) so that rounding never
        flips a verdict.
    collision_chi2 : the squared radius the collision checks use (edges and
        sample ellipses against obstacles and walls), at least the
        scenario's chi2, which the target containment keeps; None: the
        scenario's chi2. ``plan(..., risk=Delta)`` sets it from the budget
        (:mod:`.budget`).
    progress : show a tqdm progress bar.
    backend : how a 2-D attempt runs: ``"auto"`` (the default: numba when
        installed and supported, else numpy), ``"numpy"`` (the reference)
        or ``"numba"`` (compiled, :mod:`.compiled`: the same steps and
        collision layers, about 7x less CPU on paper-multi, docs/planner.md;
        needs the ``belief-nlp[fast]`` extra, 2-D scenarios and the entropy
        or hellinger metric; the first plan of a machine compiles for about
        12 s, cached on disk). The two draw the same samples but round
        differently, so their trees part at the first tie that rounding
        decides; their cost distributions are the same, and
        ``PlanResult.stats["backend"]`` records which one ran.
    """

    n_nodes: int = 500
    seed: int | None = 0
    alpha: float | None = None
    metric: str = "entropy"
    info_unit: str = "nats"
    noise: str = "per_metre"
    time_limit: float | None = None
    branch_and_bound: bool = True
    prune_every: int = 1
    eig_range: tuple[float, float] = (1e-9, 1e-1)
    eig_ratio: float = 10.0
    steering: str = "geodesic"
    max_radius: float = 0.5
    radius_per_alpha: float | None = None
    gamma: float | None = None
    goal_bias: float = 0.05
    convergence_tol: float | None = None
    convergence_window: int = 200
    max_attempts: int | None = None
    safety_margin: float = 1e-6
    progress: bool = False
    collision_chi2: float | None = None
    # "numpy" until seed-sensitive tests elsewhere allow "auto" (docs/planner.md, fourth round)
    backend: str = "auto"

    @property
    def radius_cap(self) -> float:
        """The rewiring radius's cap: max_radius + radius_per_alpha * alpha."""
        return self.max_radius + self.radius_per_alpha * self.alpha

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict (tuples become lists)."""
        out = asdict(self)
        out["eig_range"] = list(self.eig_range)
        return out


_FIELDS = {f.name for f in fields(PlannerOptions)}


def default_gamma(dim: int, domain_volume: float) -> float:
    """The authors' radius constant: 50 * (2 + 2/d)^(1/d) * (mu(X) / zeta_d) / d.

    (Their ``gamma_star`` times the factor 50 of their radius schedule; in 2-D
    on the unit square it is 13.78, so the cap max_radius = 0.5 stays active
    up to about 7000 nodes.)
    """
    zeta = math.pi ** (dim / 2) / math.gamma(dim / 2 + 1)
    return 50.0 * (2.0 + 2.0 / dim) ** (1.0 / dim) * (domain_volume / zeta) / dim


def _is_int(v: Any) -> bool:
    return isinstance(v, (numbers.Integral, np.integer)) and not isinstance(v, (bool, np.bool_))


def _is_real(v: Any) -> bool:
    return isinstance(v, (numbers.Real, np.floating, np.integer)) and not isinstance(v, (bool, np.bool_))


def _positive_int(name: str, v: Any, minimum: int = 1) -> int:
    if not _is_int(v) or int(v) < minimum:
        raise ValidationError(name, f"must be an integer >= {minimum}, got {v!r}")
    return int(v)


def _real(name: str, v: Any, low: float | None = None, high: float | None = None,
          low_open: bool = False, high_open: bool = False) -> float:
    try:
        x = float(v) if _is_real(v) else math.nan
    except OverflowError:  # an integer too large for a float
        x = math.nan
    if not math.isfinite(x):
        raise ValidationError(name, f"must be a finite number, got {v!r:.40}")
    if low is not None and (x < low or (low_open and x == low)):
        raise ValidationError(name, f"must be {'>' if low_open else '>='} {low:g}, got {x:g}")
    if high is not None and (x > high or (high_open and x == high)):
        raise ValidationError(name, f"must be {'<' if high_open else '<='} {high:g}, got {x:g}")
    return x


def _choice(name: str, v: Any, allowed: tuple[str, ...]) -> str:
    if not isinstance(v, str) or v not in allowed:
        raise ValidationError(name, f"must be one of {', '.join(map(repr, allowed))}, got {v!r}")
    return v


def _bool(name: str, v: Any) -> bool:
    if not isinstance(v, (bool, np.bool_)):
        raise ValidationError(name, f"must be true or false, got {v!r}")
    return bool(v)


def resolve_options(scenario_defaults: dict | None, scenario_alpha: float, scenario_chi2: float = 0.0,
                    **kwargs: Any) -> PlannerOptions:
    """Merge defaults < ``scenario_defaults`` < ``kwargs`` and validate.

    Unknown keys (in either source) raise ValidationError naming the key;
    ``collision_chi2`` must be at least ``scenario_chi2``.
    """
    merged: dict[str, Any] = {}
    for source, where in ((scenario_defaults or {}, "scenario planner table"), (kwargs, "keyword")):
        for key, value in source.items():
            if key not in _FIELDS:
                raise ValidationError(key, f"unknown planner option ({where}); known: {', '.join(sorted(_FIELDS))}")
            merged[key] = value
    o = {f.name: f.default for f in fields(PlannerOptions)}
    o.update(merged)

    o["n_nodes"] = _positive_int("n_nodes", o["n_nodes"], 2)
    if o["n_nodes"] > MAX_PLANNER_NODES:
        raise ValidationError("n_nodes", f"{o['n_nodes']} is more than the limit of {MAX_PLANNER_NODES}")
    if o["seed"] is not None and (not _is_int(o["seed"]) or int(o["seed"]) < 0):
        raise ValidationError("seed", f"must be a non-negative integer or None, got {o['seed']!r:.40}")
    o["seed"] = None if o["seed"] is None else int(o["seed"])
    o["alpha"] = float(scenario_alpha) if o["alpha"] is None else _real("alpha", o["alpha"], 0.0, MAX_ALPHA)
    o["metric"] = _choice("metric", o["metric"], METRICS)
    o["info_unit"] = _choice("info_unit", o["info_unit"], INFO_UNITS)
    if o["info_unit"] == "bits" and o["metric"] != "entropy":
        raise ValidationError("info_unit", f"'bits' applies to the entropy metric only, not {o['metric']!r}")
    o["noise"] = _choice("noise", o["noise"], NOISE_MODELS)
    if o["time_limit"] is not None:
        o["time_limit"] = _real("time_limit", o["time_limit"], 0.0, low_open=True)
    o["branch_and_bound"] = _bool("branch_and_bound", o["branch_and_bound"])
    o["prune_every"] = _positive_int("prune_every", o["prune_every"])
    er = o["eig_range"]
    try:
        lo, hi = (float(v) for v in er) if not isinstance(er, (str, bytes)) and len(er) == 2 else (None, None)
    except (TypeError, ValueError, OverflowError):
        lo, hi = None, None
    if lo is None or not (math.isfinite(lo) and math.isfinite(hi)) or not 0 < lo <= hi <= MAX_VARIANCE:
        raise ValidationError("eig_range", f"must be a pair (low, high) with 0 < low <= high <= {MAX_VARIANCE:g} "
                                           f"(m^2), got {er!r:.60}")
    o["eig_range"] = (lo, hi)
    o["eig_ratio"] = _real("eig_ratio", o["eig_ratio"], 1.0, 1e12)
    o["steering"] = _choice("steering", o["steering"], STEERING)
    o["max_radius"] = _real("max_radius", o["max_radius"], 0.0, low_open=True)
    if o["radius_per_alpha"] is None:
        o["radius_per_alpha"] = PER_STEP_RADIUS_PER_ALPHA if o["noise"] == "per_step" else 0.0
    o["radius_per_alpha"] = _real("radius_per_alpha", o["radius_per_alpha"], 0.0, 1e6)
    if o["gamma"] is not None:
        o["gamma"] = _real("gamma", o["gamma"], 0.0, low_open=True)
    o["goal_bias"] = _real("goal_bias", o["goal_bias"], 0.0, 1.0, high_open=True)
    if o["convergence_tol"] is not None:
        o["convergence_tol"] = _real("convergence_tol", o["convergence_tol"], 0.0)
    o["convergence_window"] = _positive_int("convergence_window", o["convergence_window"])
    if o["max_attempts"] is not None:
        o["max_attempts"] = _positive_int("max_attempts", o["max_attempts"])
    o["safety_margin"] = _real("safety_margin", o["safety_margin"], 0.0, 0.1)
    o["progress"] = _bool("progress", o["progress"])
    if o["collision_chi2"] is not None:
        # below the scenario's chi2 the collision checks of verify(scenario, path) would fail
        o["collision_chi2"] = _real("collision_chi2", o["collision_chi2"], float(scenario_chi2), MAX_CHI2)
    o["backend"] = _choice("backend", o["backend"], BACKENDS)
    return PlannerOptions(**o)
