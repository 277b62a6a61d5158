"""Where a CCP step comes from: the compiled CVXPY problem and the active-set
step's conic data of a model, each built once per (scenario, K) and kept in
memory (and on disk with the disk cache); for a re-plan after executed
steps, the step of the longer horizon still in memory with those steps
frozen (:mod:`belief_nlp.model.conic_prefix`); and the active-set step built
in a background thread while IPOPT solves (:func:`prefetch_conic_step`:
``auto``'s first call on a model, whose CCP polish needs it afterwards).

Why a thread works: CasADi's wheels are built with thread-safe symbolics
(``CASADI_WITH_THREADSAFE_SYMBOLICS``) and IPOPT's solve releases the GIL,
so the build (76-110 ms at K = 20) runs on the other core beside the solve
(docs/performance.md, "Smoothing: the first call of a process").
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from ..errors import ValidationError
from ..model import BeliefModel
from ..model.cache import MEMORY, DiskCache, disk_cache, problem_key
from ..model.conic_form import ConicStep, conic_step
from ..model.conic_prefix import FrozenConic, frozen_conic
from ..model.cvxpy_form import CompiledProblem, compile_problem
from ..model.nlp_prefix import longer
from ..smoother.policy import DEFAULT_POLICY
from . import background

__all__ = ["CHI2_MARGIN", "compiled_step", "conic_step_of", "frozen_step", "prefetch_conic_step", "PREFETCH"]

CHI2_MARGIN = DEFAULT_POLICY.conic      # every collision/containment row of the step asks chi2 (1 + this)

#: build the active-set step in the background when asked (:func:`prefetch_conic_step`);
#: False: only where a step needs it, in the caller's thread
PREFETCH = True


def compiled_step(model: BeliefModel, solver: str = "CLARABEL", cache_dir: str | Path | bool | None = None,
                  chi2_margin: float = CHI2_MARGIN, proximal: float = 0.0) -> tuple[CompiledProblem, str, DiskCache | None]:
    """The compiled CVXPY problem of ``model``'s CCP step: from memory, from the
    disk cache (``cache_dir``: None = the process's, :func:`belief_nlp.set_disk_cache`;
    True = the user's cache folder; a folder; False = none), else compiled.
    ``proximal``: the step with that proximal weight
    (:func:`belief_nlp.model.doc.convex_form`). Returns (problem, where it
    came from, the disk cache)."""
    key = problem_key(model.data, chi2_margin, solver, proximal)
    hit = MEMORY.get(key)
    disk = _disk(cache_dir)
    if hit is not None:
        return _for_model(hit, model), "memory", disk
    if disk is not None:
        hit = disk.load(key)
        if isinstance(hit, CompiledProblem):
            MEMORY.put(key, hit)
            return _for_model(hit, model), "disk", disk
    form = model.convex_form if chi2_margin == CHI2_MARGIN and not proximal else None
    if form is None:
        from ..model.doc import convex_form

        form = convex_form(model.data, chi2_margin, proximal)
    step = compile_problem(form)
    MEMORY.put(key, step)
    return step, "compiled", disk


def _disk(cache_dir: str | Path | bool | None) -> DiskCache | None:
    """The disk cache a ``cache_dir`` option means (None: the process's)."""
    if cache_dir is None:
        return disk_cache()
    if cache_dir is False:
        return None
    return DiskCache(None if cache_dir is True else cache_dir)


def _conic_key(model: BeliefModel) -> str:
    """Memory (and disk) key of ``model``'s active-set step."""
    return problem_key(model.data, CHI2_MARGIN, "CLARABEL-direct")


def conic_step_of(model: BeliefModel, cache_dir: str | Path | bool | None = None) -> ConicStep:
    """The model's step as Clarabel's own data (:mod:`belief_nlp.model.conic_form`),
    built once per model key: from memory, from a background build
    (:func:`prefetch_conic_step`; waited for), from the disk cache
    (``cache_dir`` as in :func:`compiled_step`), else built."""
    key = _conic_key(model)
    hit = MEMORY.get(key)
    if hit is None:
        _settle()
        hit = MEMORY.get(key) or background.take(key)[1]
        disk = _disk(cache_dir)
        if hit is None and disk is not None:
            hit = disk.load(key, kind="conic")
            if isinstance(hit, ConicStep):
                disk = None                 # it is there already
        if not isinstance(hit, ConicStep):
            hit = conic_step(model.convex_form)
        if disk is not None:
            disk.save(key, hit, kind="conic")
        MEMORY.put(key, hit)
    return _for_model(hit, model)


def prefetch_conic_step(model: BeliefModel) -> bool:
    """Start building ``model``'s active-set step in a background thread
    (:mod:`.background`; :func:`conic_step_of` takes it from there); whether
    a build started. Not when :data:`PREFETCH` is off, the step is in memory
    or building, the process keeps a disk cache (the step may be there, and
    reading it in the caller is cheap), or one CPU is all this process may use."""
    _settle()
    key = _conic_key(model)
    if not PREFETCH or background.running(key) or MEMORY.get(key) is not None or disk_cache() is not None:
        return False
    return background.start(key, lambda: conic_step(model.convex_form))


def _settle() -> None:
    """Finished background builds into the memory cache (a step built for an
    answer that needed no polish is kept for the next call on the model)."""
    for key, step in background.settle():
        if isinstance(step, ConicStep) and MEMORY.get(key) is None:
            MEMORY.put(key, step)


def frozen_step(model: BeliefModel, prefix: int) -> FrozenConic | None:
    """The active-set step of the horizon ``prefix`` steps longer, with those
    steps frozen at the model's start, when that step is in memory (a
    re-plan's previous answer built it); None otherwise."""
    try:
        hit = MEMORY.get(problem_key(longer(model, prefix).data, CHI2_MARGIN, "CLARABEL-direct"))
        return frozen_conic(hit, model.data, prefix) if isinstance(hit, ConicStep) else None
    except ValidationError:
        return None


def _for_model(step, model: BeliefModel):
    """A cached step (compiled for any alpha and start belief: both are its
    parameters) as ``model``'s: the same compiled problem, a layout with
    ``model``'s data."""
    layout = step.layout.for_data(model.data)
    return step if layout is step.layout else replace(step, layout=layout)
