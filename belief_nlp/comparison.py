"""Compare smoothing methods on one path, from one warm start.

``compare(scenario, path)`` builds the warm start once (:func:`warm_start`),
hands the same :class:`~belief_nlp.smoother.warmstart.WarmStart` to
:func:`belief_nlp.smooth` for every method and returns one flat record (a
dict) per method, ready for a table, a JSON file or a DataFrame. A method
that raises a :class:`~belief_nlp.errors.BeliefNLPError` gives a record with
``status="error"`` and the message; the others still run.

Record keys
-----------
method, status, success, message : as in :class:`SmoothResult` ("error" if it raised)
cost, control, information : the objective (control in m^2, information in nats)
initial_cost : cost of the shared warm start
iterations : CCP iterations or IPOPT iterations (not comparable one to one)
wall_time : seconds around ``smooth`` (model building included)
solver_time, setup_time : the method's own split (``SmoothResult.timings``)
safe : the returned path passed :func:`belief_nlp.verify`
worst_margin : verify's smallest margin (squared Mahalanobis distance minus chi2)
worst : verify's worst offender
alpha, K, scenario : the problem
warm_start_time : seconds to build the shared warm start (0 when a WarmStart was given)
error : the exception's message, or None
history : list of per-iteration dicts (``IterationRecord``); path : the BeliefPath
    (both dropped by :func:`compact`, which is what the benchmark scripts write)
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict
from typing import Any, Iterable, Mapping

from .errors import BeliefNLPError, ValidationError
from .smoother.registry import available_methods, resolve_method
from .smoother.warmstart import WarmStart, warm_start
from .path import BeliefPath
from .scenario import Scenario, load_scenario

__all__ = ["compare", "records_to_table", "compact", "RECORD_KEYS"]

RECORD_KEYS = ("method", "status", "success", "message", "cost", "control", "information", "initial_cost",
               "iterations", "wall_time", "solver_time", "setup_time", "safe", "worst_margin", "worst", "alpha",
               "K", "scenario", "warm_start_time", "error", "history", "path")


def _per_method(value: Any, method: str, default: Any = None) -> Any:
    if isinstance(value, Mapping):
        return value.get(method, default)
    return default if value is None else value


def _name(spec: Any) -> str:
    """A method's name for a record, before it is resolved."""
    return spec if isinstance(spec, str) else getattr(spec, "name", getattr(spec, "__name__", "custom"))


def _error_record(method: str, message: str, base: dict) -> dict:
    rec = {k: None for k in RECORD_KEYS}
    rec.update(base)
    nan = math.nan
    rec.update(method=method, status="error", success=False, message=message, error=message, cost=nan,
               control=nan, information=nan, iterations=0, wall_time=nan, solver_time=nan, setup_time=nan,
               safe=False, worst_margin=nan, worst="", history=[], path=None)
    return rec


def compare(scenario: Scenario | str, path: BeliefPath | WarmStart, methods: Iterable[Any] | None = None, *,
            K: int | None = None, max_iter: int | Mapping[str, int] | None = None,
            method_options: Mapping[str, Mapping[str, Any]] | None = None, sensing: str = "minimal",
            **common_options: Any) -> list[dict]:
    """Smooth ``path`` with each method from one shared warm start.

    Parameters
    ----------
    scenario : Scenario or str
        The scenario, or a built-in name / scenario file.
    path : BeliefPath or WarmStart
        A feasible path (the warm start is built once from it, with ``K`` and
        ``sensing`` as in :func:`belief_nlp.warm_start`), or a warm start.
    methods : iterable, optional
        Smoothing methods: names from :func:`available_methods`, registered
        :class:`Method` objects or callables; None runs every registered method.
    K : int, optional
        Horizon of the warm start; None as in :func:`warm_start`.
    max_iter : int or dict, optional
        One limit for all, a dict per method name, or None for each method's
        own default (the same as :func:`smooth`'s).
    method_options : dict, optional
        Per-method keywords for ``smooth``, e.g.
        ``{"ipopt": {"formulation": "minors", "solver_options": {...}}}``.
    sensing : {"minimal", "path"}, optional
        How the warm start sets the covariances (see :func:`warm_start`).
    **common_options
        Keywords for every ``smooth`` call (``alpha``, ``tol``,
        ``time_limit``, ``solver``, ``progress``, ...).

    Returns
    -------
    list of dict
        One record per method, in ``methods`` order (keys: ``RECORD_KEYS``,
        described in the module docstring of :mod:`belief_nlp.comparison`); a
        method that raised a BeliefNLPError gives a record with ``status="error"``
        and its message.

    See Also
    --------
    records_to_table : the records as a table.
    """
    from .inputs import as_path
    from .smoother.driver import smooth

    if isinstance(scenario, str):
        scenario = load_scenario(scenario)
    path = as_path(path)
    methods = list(available_methods() if methods is None else methods)
    if not methods:
        raise ValidationError("methods", "give at least one method")
    alpha = common_options.get("alpha")
    alpha = float(scenario.alpha if alpha is None else alpha)
    base = {"alpha": alpha, "scenario": scenario.name, "K": None, "initial_cost": math.nan,
            "warm_start_time": 0.0}
    t0 = time.perf_counter()
    if isinstance(path, WarmStart):
        start = path
        if K is not None and K != start.K:
            raise ValidationError("K", f"the given warm start has K = {start.K}, not {K}")
    else:
        try:
            start = warm_start(scenario, path, K=K, sensing=sensing)
        except BeliefNLPError as exc:
            msg = f"warm start failed: {exc}"
            return [_error_record(_name(m), msg, base) for m in methods]
    base["warm_start_time"] = 0.0 if start is path else time.perf_counter() - t0
    base["K"] = start.K

    records = []
    for spec in methods:
        method = _name(spec)
        try:
            m = resolve_method(spec)
        except BeliefNLPError as exc:
            records.append(_error_record(method, f"{type(exc).__name__}: {exc}", base))
            continue
        opts = dict(common_options)
        opts.update(dict(_per_method(method_options, method, {}) or {}))
        limit = _per_method(max_iter, method, None)
        t = time.perf_counter()
        try:
            res = smooth(scenario, start, method=m, max_iter=limit, **opts)
        except BeliefNLPError as exc:
            records.append(_error_record(method, f"{type(exc).__name__}: {exc}", base))
            continue
        wall = time.perf_counter() - t
        ver = res.verification
        rec = dict(base)
        rec.update(
            method=method, status=res.status, success=bool(res.success), message=res.message,
            cost=float(res.cost), control=float(res.control), information=float(res.information),
            initial_cost=float(res.initial_cost), iterations=int(res.nit), wall_time=wall,
            solver_time=float(res.timings.get("solver", math.nan)),
            setup_time=float(res.timings.get("setup", math.nan)), safe=bool(res.safe),
            worst_margin=float(ver.get("min_margin", math.nan)), worst=str(ver.get("worst", "")),
            alpha=float(res.alpha), error=None, history=[asdict(h) for h in res.history], path=res.path)
        records.append({k: rec.get(k) for k in RECORD_KEYS})
    return records


def compact(record: Mapping[str, Any]) -> dict:
    """The record without its bulky entries (``history``, ``path``): what the
    benchmark scripts store. Extra keys (seed, ...) are kept."""
    return {k: v for k, v in record.items() if k not in ("history", "path")}


_COLUMNS = [
    ("method", "method", "{}"),
    ("status", "status", "{}"),
    ("cost", "cost", "{:.6g}"),
    ("control", "control m^2", "{:.4g}"),
    ("information", "info nats", "{:.4g}"),
    ("iterations", "iters", "{:d}"),
    ("wall_time", "wall s", "{:.2f}"),
    ("solver_time", "solver s", "{:.2f}"),
    ("safe", "safe", "{}"),
    ("worst_margin", "worst margin", "{:.2g}"),
]
_KEY_COLUMNS = [("scenario", "scenario", "{}"), ("seed", "seed", "{}"), ("alpha", "alpha", "{:g}"),
                ("K", "K", "{}")]


def _fmt(value: Any, spec: str) -> str:
    if value is None:
        return "-"
    if isinstance(value, float) and math.isnan(value):
        return "nan"
    try:
        return spec.format(value)
    except (ValueError, TypeError):
        return str(value)


def records_to_table(records: Iterable[Mapping[str, Any]], columns: list[tuple[str, str, str]] | None = None) -> str:
    """A plain-text (Markdown-compatible) table of comparison records.

    Parameters
    ----------
    records : iterable of dict
        Records from :func:`compare` (or study rows with the same keys).
    columns : list of (key, header, format), optional
        The columns to show instead of the defaults; ``format`` is a format
        spec such as ``".4g"``.

    Returns
    -------
    str
        One row per record. Identifying columns (scenario, seed, alpha, K)
        are added in front when the records vary in them; error records show
        their message.
    """
    records = list(records)
    if not records:
        return "(no records)"
    if columns is None:
        columns = [c for c in _KEY_COLUMNS
                   if len({repr(r.get(c[0])) for r in records}) > 1 and any(c[0] in r for r in records)]
        columns = columns + _COLUMNS
    header = [h for _, h, _ in columns]
    rows = []
    notes = []
    for r in records:
        rows.append([_fmt(r.get(k), spec) for k, _, spec in columns])
        if r.get("status") == "error":
            notes.append(f"{r.get('method')}: {r.get('error') or r.get('message')}")
    widths = [max(len(h), *(len(row[i]) for row in rows)) for i, h in enumerate(header)]
    line = lambda cells: "| " + " | ".join(c.ljust(w) for c, w in zip(cells, widths)) + " |"  # noqa: E731
    out = [line(header), "|" + "|".join("-" * (w + 2) for w in widths) + "|"]
    out += [line(row) for row in rows]
    if notes:
        out.append("")
        out += [f"error: {n}" for n in notes]
    return "\n".join(out)
