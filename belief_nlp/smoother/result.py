"""SmoothResult: the result type shared by every smoothing method."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._limits import check_npz, load_json, parse_document
from ..errors import ScenarioFileError, ValidationError
from ..allocation import RiskAllocation
from ..path import BeliefPath

__all__ = ["IterationRecord", "SmoothResult", "STATUSES"]

# Status strings, in one place, shared by every method. ``success`` is True
# only for "converged", and never for an answer above the warm start.
STATUSES = {
    "converged": "relative cost decrease fell below tol",
    "max_iter": "iteration limit reached (not converged; the best feasible iterate is returned)",
    "time_limit": "wall-time limit reached (best feasible iterate returned)",
    "solver_failed": "the solver failed, or a CCP subproblem twice (best feasible iterate returned)",
    "non_monotone": "a step would have increased the cost beyond tolerance (rejected; best iterate returned)",
    "infeasible_iterate": "a solver answer failed the exact safety check (rejected; best iterate returned)",
    "ipopt_failed": "the NLP solver did not reach an acceptable point (best feasible point returned)",
    "above_start": "the method's answer cost more than the warm start, beyond tol (the warm start is returned)",
    "stopped": "stopped by the callback (best feasible iterate returned)",
}


def _load_npz(filename: Path) -> dict:
    """The document of a result NPZ written by :meth:`SmoothResult.save`."""
    import zipfile
    import zlib

    check_npz(filename, "filename")
    try:
        with np.load(filename, allow_pickle=False) as z:
            header = z["smooth_header"]
            cert = z["certificates"] if "certificates" in z.files else None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
        raise ScenarioFileError("filename", f"{str(filename)[:200]}: not a smoothing-result NPZ file: "
                                            f"{str(exc)[:200]}") from None
    if header.ndim != 0 or header.dtype.kind != "U":
        raise ValidationError("result", "the NPZ header must be a single string")
    data = parse_document(str(header), "json", f"{str(filename)[:200]} (header)", "filename")
    if isinstance(data, dict):
        data["certificates"] = None if cert is None else cert
    return data


def _same(a: Any, b: Any) -> bool:
    """Structural equality of JSON-like data with NaN == NaN."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, float) and isinstance(b, float) and a != a and b != b:
        return True
    return a == b


@dataclass
class IterationRecord:
    """One iteration of a smoothing method (iteration 0 is the warm start).

    The fields mean the same for every method. A record reads like a dict
    too (``record["cost"]``).

    Parameters
    ----------
    iteration : int
        0 for the warm start, then 1, 2, ...
    cost : float
        The paper's objective at the iterate, ``control + alpha * information``
        (SI units, nats).
    control : float
        Control effort, sum of ||x_k - x_{k-1}||^2 (m^2).
    information : float
        Information gathered by sensing (nats).
    solver_status : str, optional
        The solver's own status for this iteration.
    solve_time : float, optional
        The solver's own time, s.
    build_time : float, optional
        Assembling or updating the subproblem, s.
    wall_time : float, optional
        The whole iteration, s.
    solver_iterations : int, optional
        The solver's inner iterations.
    accepted : bool, optional
        True when the iterate passed the method's exact safety check and may
        become the answer.
    min_margin : float, optional
        The smallest constraint margin the method measured (the exact
        clearance minus chi2 where the method checks exactly); NaN if none.
    kalman_gap : float, optional
        Largest relative gap of the solver's information matrices Q_k to the
        Kalman recursion (Lemma 2); NaN if not measured.
    """

    iteration: int
    cost: float
    control: float
    information: float
    solver_status: str = ""
    solve_time: float = 0.0          # the solver's own time, s
    build_time: float = 0.0          # assembling / updating the subproblem, s
    wall_time: float = 0.0           # whole iteration, s
    solver_iterations: int = 0
    accepted: bool = True            # exactly safe by the method's own check: a candidate answer
    min_margin: float = float("nan")
    kalman_gap: float = float("nan")  # max rel. gap of the solver's Q_k to the Kalman recursion (Lemma 2)

    def __getitem__(self, key: str) -> Any:     # records read like dicts too
        return getattr(self, key)


@dataclass
class SmoothResult:
    """Outcome of :func:`belief_nlp.smooth` (scipy.optimize-style).

    Built by the smoothing driver; reloaded with :meth:`load`.

    Attributes
    ----------
    path : BeliefPath
        The smoothed path (SI units), always the best exactly safe iterate.
    cost : float
        ``sum ||x_k - x_{k-1}||^2 + alpha * information`` (nats): the paper's objective.
    control, information : float
        The two parts of ``cost``.
    success : bool
        True when the method converged (see ``status``).
    status : str
        One of :data:`~belief_nlp.STATUSES`.
    message : str
        The status in a sentence.
    nit : int
        Iterations performed (accepted or not).
    history : list of IterationRecord
        One record per iteration, index 0 the warm start (a solver that
        reports only where each solve ended, fatrop, has one record per
        solve, numbered by its iteration count).
    method : str
        The method that answered (``"auto:ipopt+ccp"``, ``"auto:ccp"``, ``"ccp"``, ...).
    solver : str
        The solver it used.
    alpha : float
        The information weight of the run.
    timings : dict
        ``{"setup", "total", "solver"}`` in seconds.
    verification : dict
        ``verify(scenario, path).to_dict()`` of the returned path.
    initial_cost : float
        Cost of the warm start.
    iterates : list of BeliefPath or None
        With ``keep_iterates``, the path of every accepted iterate (the warm
        start first).
    stats : dict
        The solver's raw statistics (return status, iterations, times).
    certificates : ndarray or None
        (K, J, F) Theorem-1 certificates of the returned path in 1/m
        (hazards as ``scenario.hazards``, faces padded with 0): the proof
        :func:`belief_nlp.verify` checks in closed form (docs/safety.md).
    risk : RiskAllocation or None
        With a risk budget (``smooth(..., risk=Delta)``): the budget, each
        transition-hazard pair's level and allotted risk (K, J), and the
        certified end-to-end bound of the returned path; None otherwise.
    resume : dict or None
        What a re-plan on the same scenario can start from, on the same K or
        after executed steps (:func:`belief_nlp.replan` passes it on): for
        IPOPT's first stage (methods ``ipopt`` and ``auto``) its converged
        variables and multipliers (and its polish's), and the NLP graph they
        belong to; for ``fatrop`` and ``sqp`` the graph alone (they take no
        multipliers); for ``ccp`` the steps its conic step's horizon is
        longer by (``offset``); None for other methods. In memory only: not
        saved, not compared.
    """

    path: BeliefPath
    cost: float
    control: float
    information: float
    success: bool
    status: str
    message: str
    nit: int
    history: list[IterationRecord]
    method: str
    solver: str
    alpha: float
    timings: dict = field(default_factory=dict)
    verification: dict = field(default_factory=dict)
    initial_cost: float = float("nan")
    iterates: list[BeliefPath] | None = field(default=None, repr=False)
    stats: dict = field(default_factory=dict)
    certificates: np.ndarray | None = field(default=None, repr=False)
    risk: RiskAllocation | None = field(default=None, repr=False)
    resume: dict | None = field(default=None, repr=False, compare=False)

    @property
    def x(self) -> np.ndarray:
        """The smoothed means, ``path.x`` of shape (K+1, d) (scipy's name for the answer)."""
        return self.path.x

    @property
    def fun(self) -> float:
        """The cost, ``cost`` (scipy's name for the objective value)."""
        return self.cost

    @property
    def safe(self) -> bool:
        """True when the independent verifier passed the returned path (``verification["safe"]``)."""
        return bool(self.verification.get("safe", False))

    def to_dict(self) -> dict:
        """The result as JSON-ready data (what :meth:`save` writes).

        Returns
        -------
        dict
            Every field; ``path`` as :meth:`BeliefPath.to_dict`, ``history``
            as a list of dicts, ``certificates`` as nested lists (or None).
        """
        out = {k: v for k, v in asdict(self).items()
               if k not in ("path", "history", "iterates", "certificates", "risk", "resume")}
        out["risk"] = None if self.risk is None else self.risk.to_dict()
        out["certificates"] = None if self.certificates is None else np.asarray(self.certificates).tolist()
        out["path"] = self.path.to_dict()
        out["history"] = [asdict(h) for h in self.history]
        return out

    def save(self, filename: str | Path) -> Path:
        """Write as ``.json`` (one document) or ``.npz`` (the certificates as an
        array, the rest as a JSON header, as plans do); :meth:`load` reads
        either back equal."""
        filename = Path(filename)
        if filename.suffix not in (".json", ".npz"):
            raise ValidationError("filename", f"smoothing results are saved as .json or .npz, got {filename.suffix!r}")
        data = self.to_dict()
        try:
            if filename.suffix == ".json":
                filename.write_text(json.dumps(data, default=float))
            else:
                cert = data.pop("certificates")
                arrays = {"smooth_header": np.array(json.dumps(data, default=float))}
                if cert is not None:
                    arrays["certificates"] = np.asarray(cert, float)
                np.savez_compressed(filename, **arrays)
        except OSError as exc:
            raise ScenarioFileError("filename", f"cannot write {str(filename)[:200]}: {exc.strerror or exc}") from None
        return filename

    @classmethod
    def load(cls, filename: str | Path) -> "SmoothResult":
        """Read a result written by :meth:`save`, JSON or NPZ (file limits as
        :meth:`BeliefPath.load`); file faults raise :class:`ScenarioFileError`,
        bad contents :class:`ValidationError`."""
        filename = Path(filename)
        if filename.suffix == ".npz":
            data = _load_npz(filename)
        else:
            data = load_json(filename, "filename")
        if not isinstance(data, dict) or not {"path", "history"} <= set(data):
            raise ValidationError("result", "not a smoothing result (needs 'path' and 'history')")
        data = dict(data)
        try:
            data["path"] = BeliefPath.from_dict(data["path"])
            data["history"] = [IterationRecord(**h) for h in data["history"]]
            if data.get("certificates") is not None:
                data["certificates"] = np.asarray(data["certificates"], dtype=float)
            if data.get("risk") is not None:
                data["risk"] = RiskAllocation.from_dict(data["risk"])
            return cls(**data)
        except (TypeError, KeyError, AttributeError) as exc:
            raise ValidationError("result", f"malformed smoothing result: {str(exc)[:200]}") from None

    def __eq__(self, other: object) -> bool:
        """Equal content, NaN equal to NaN (results reload equal)."""
        if not isinstance(other, SmoothResult):
            return NotImplemented
        return _same(json.loads(json.dumps(self.to_dict(), default=float)),
                     json.loads(json.dumps(other.to_dict(), default=float)))

    def summary(self) -> str:
        """A few lines for people: status, the cost and its parts, proof, time."""
        from .registry import iterations_counted

        head = "converged" if self.success else f"NOT converged ({self.status})"
        v = self.verification
        lines = [f"{self.method} {head}: {self.message}",
                 f"  steering cost at K = {self.path.K}: {self.initial_cost:.6g} (warm start) -> {self.cost:.6g} "
                 f"= control {self.control:.6g} m^2 + {self.alpha:g} * information {self.information:.6g} nats",
                 f"  {iterations_counted(self.nit, self.method)}, {self.timings.get('total', float('nan')):.3g} s "
                 f"(solver {self.timings.get('solver', float('nan')):.3g} s); solver {self.solver or '-'}",
                 f"  verified {'safe' if self.safe else 'UNSAFE'} by {v.get('proof', 'sampling')}, "
                 f"min margin {v.get('min_margin', float('nan')):.4g}"]
        if v.get("risk_step_time") is not None:
            lines.append(f"  collision probability <= {v['risk_step_time']:.3g} at the step times "
                         f"(certified; Boole over transition-hazard pairs, bn.verify(...).risk)")
        if self.risk is not None:
            lines.append(f"  {self.risk.summary()}")
        return "\n".join(lines)

    def __repr__(self) -> str:
        return (f"SmoothResult(method={self.method!r}, status={self.status!r}, cost={self.cost:.6g}, "
                f"nit={self.nit}, success={self.success})")
