"""The NLP methods' graphs and solver instances: built once per (scenario, K,
options) and kept in memory; with the disk cache on
(:func:`belief_nlp.set_disk_cache`), the graph's symbolic part and IPOPT's
derivative functions are loaded from an earlier process instead of built
(docs/numerics.md, "The disk cache"). Used by :mod:`.nlp_engine`."""

from __future__ import annotations

import hashlib
from typing import Any

import casadi as ca

from ..errors import ValidationError
from ..model.cache import MODEL_REVISION, MemoryCache, compile_enabled, disk_cache, problem_key
from ..model.evaluate import BeliefModel
from ..model.nlp_form import NLPProblem, build_nlp
from ..model.nlp_prefix import frozen, longer
from . import nlp_compiled, solver_logs
from .nlp_backend import NLPBackend
from .nlp_recorder import Recorder
from .nlp_scaled import scaled

__all__ = ["clear_cache", "solver_of"]

# solvers: 16, every NLP method's two stages (alpha is a parameter) at a few K
# (IPOPT, fatrop, Uno); NLP graphs with the derivatives built on them: 8
_CACHE = MemoryCache(16)
_GRAPHS = MemoryCache(8)


def clear_cache() -> None:
    """Drop every cached NLP / solver instance."""
    _CACHE.clear()
    _GRAPHS.clear()


def _base_key(model: BeliefModel, formulation: str, margin: float, regularisation: float) -> str:
    """Key of an NLP graph: the model's data without alpha (the NLP's
    parameter), the margin, the regularisation and the formulation ("cholesky"
    and "logchol" are one graph, :meth:`NLPProblem.variant`)."""
    family = "cholesky|logchol" if formulation in ("cholesky", "logchol") else formulation
    return problem_key(model.data, margin, f"nlp:{family}:{regularisation}")


def _nlp(model: BeliefModel, formulation: str, margin: float, regularisation: float, floor: float,
         cache: bool) -> tuple[NLPProblem, dict]:
    """The NLP of ``formulation`` and the derivative functions solvers built
    on its graph so far (by plug-in), from the cache when the graph is there."""
    key = _base_key(model, formulation, margin, regularisation)
    entry = _GRAPHS.get(key) if cache else None
    if entry is None:
        # the graph's symbolic part from another process (disk cache), else built and kept there
        disk = disk_cache() if cache else None
        graph = disk.load(key, kind="graph") if disk is not None else None
        valid = isinstance(graph, dict) and isinstance(graph.get("function"), ca.Function)
        entry = (build_nlp(model, formulation, margin=margin, regularisation=regularisation, floor=floor,
                           graph=graph if valid else None), {})
        if disk is not None and not valid:
            disk.save(key, entry[0].graph, kind="graph")
        if cache:
            _GRAPHS.put(key, entry)
    base, shared = entry
    nlp = base if base.formulation == formulation and base.info.get("floor") == floor \
        else base.variant(formulation, floor)
    return nlp, shared


def solver_of(model: BeliefModel, backend: NLPBackend, opts: dict, formulation: str, margin: float,
              regularisation: float, floor: float, candidates: int, cache: bool,
              scale: float = 1.0, prefix: int = 0) -> tuple[NLPProblem, Any, Recorder, str]:
    """NLP, nlpsol instance and recorder of ``model``, from the cache when the
    model and options match; ``scale`` != 1: the NLP with its means scaled
    (:func:`.nlp_scaled.scaled`, option ``scale_means`` of method "ipopt");
    ``prefix`` > 0: the NLP of ``prefix`` more steps with those frozen at the
    model's start (:func:`belief_nlp.model.nlp_prefix.frozen`), its solver.
    The recorder is bound to the NLP returned."""
    if prefix:
        nlp, solver, recorder, source = solver_of(longer(model, prefix), backend, opts, formulation, margin,
                                                  regularisation, floor, candidates, cache, scale)
        nlp = frozen(nlp, model, prefix)
        recorder.bind(nlp)
        return nlp, solver, recorder, source
    # the floor shapes only the "logchol" NLP: it stays out of the other
    # formulations' keys (no second build of an identical NLP); alpha is the
    # NLP's parameter, not part of it: one solver serves every alpha
    floor_key = floor if formulation == "logchol" else None
    scale_key = "" if scale == 1 else f":scale_means={float(scale)!r}"
    key = problem_key(model.data, margin,
                      f"{backend.plugin}:{formulation}:{regularisation}:{floor_key}{scale_key}:{sorted(opts.items())!r}")
    entry = _CACHE.get(key) if cache else None
    if entry is not None and solver_logs.full(entry[2].log_path):
        entry = None          # a new solver and log; the old log goes with its recorder
    if entry is not None:
        # the key leaves out the start belief (a parameter): read this model's
        entry[2].bind(entry[0])
        return entry[0].for_model(model), entry[1], entry[2], "memory"
    view, shared = _nlp(model, formulation, margin, regularisation, floor, cache)
    nlp = backend.form(view)
    if scale != 1:
        if nlp is not view:
            raise ValidationError("scale_means", f"applies to IPOPT's NLP, not to {backend.name}'s stage-ordered form")
        nlp = scaled(view, scale)
    # derivatives of this NLP's own graph (the plain NLP's, or its scaled
    # form's) built by an earlier solver of this plug-in (the other stage's,
    # or another process's through the disk cache) are handed over instead
    # of derived again
    own = nlp is view or scale != 1
    slot = backend.plugin + scale_key
    given, source, fill = _given_derivatives(nlp, backend, shared, slot, cache) if own else ({}, "", None)
    recorder = Recorder(nlp, keep=candidates, bar=None, stall=0, pad=backend.pads(opts))
    recorder.log_path = backend.log_file()
    solver_logs.tie(recorder, recorder.log_path)
    name = f"belief_nlp_{backend.plugin}" + ("_scaled" if scale != 1 else "")
    try:
        solver = backend.nlpsol(name, {"x": nlp.z, "p": nlp.p, "f": nlp.f, "g": nlp.g},
                                {**backend.nlpsol_options(opts, recorder.log_path), **backend.structure_options(nlp),
                                 **given, "print_time": False, "iteration_callback": recorder,
                                 "error_on_fail": False, "show_eval_warnings": False})
    except RuntimeError as exc:  # bad option names or values
        raise ValidationError("solver_options",
                              f"{backend.name} refused them: {str(exc).splitlines()[-1][:200]}") from None
    if own and backend.shared_functions and not given:
        shared[slot] = _derivatives(solver, backend.shared_functions)
        if fill is not None and _complete(shared[slot], backend) \
                and fill[0].save(fill[1], shared[slot], kind="nlp") is not None and compile_enabled():
            nlp_compiled.start(*fill)
    if cache:
        _CACHE.put(key, (nlp, solver, recorder))
    return nlp.for_model(model), solver, recorder, "built" if not given else source


def _given_derivatives(nlp: NLPProblem, backend: NLPBackend, shared: dict, slot: str,
                       cache: bool) -> tuple[dict, str, Any]:
    """The derivative functions a new solver of ``nlp`` is handed, where they
    came from, and (disk, name) when the solver's own should be written to
    the disk cache (None: not wanted, or already there). Sources in order:
    this process (``shared[slot]``, filled by the other stage's solver), the
    compiled library, the serialised disk entry; ``shared[slot]`` keeps
    what the disk gave; ``cache`` False: no disk."""
    if shared.get(slot):
        return shared[slot], "built (derivatives shared)", None
    disk = disk_cache() if cache and backend.shared_functions else None
    if disk is None:
        return {}, "", None
    name = _derivatives_key(nlp, backend)
    compiled = compile_enabled()
    loaded = nlp_compiled.load(disk, name) if compiled else None
    source = "built (derivatives compiled)"
    if not _complete(loaded, backend):
        loaded, source = disk.load(name, kind="nlp"), "built (derivatives from disk)"
        if not _complete(loaded, backend):
            return {}, "", (disk, name)
        if compiled:            # an earlier build died, or was evicted: build it again
            nlp_compiled.start(disk, name)
    shared[slot] = loaded
    return loaded, source, None


def _derivatives_key(nlp: NLPProblem, backend: NLPBackend) -> str:
    """Disk-cache name of a graph's derivative functions: a hash of the graph
    itself (its CasADi serialisation, ~30 ms at K = 20), CasADi's version and
    the plug-in. The functions are derived from nothing else, so an entry
    can only be found by the graph it was derived from."""
    h = hashlib.sha256()
    for part in (MODEL_REVISION, ca.__version__, backend.plugin, sorted(backend.shared_functions.items())):
        h.update(repr(part).encode())
    h.update(nlp.fg.serialize().encode())
    return h.hexdigest()[:40]


def _complete(functions: Any, backend: NLPBackend) -> bool:
    """Every derivative function the backend shares, as CasADi functions (what
    the disk cache stores, and all a loaded entry may be used for)."""
    return isinstance(functions, dict) and set(functions) == set(backend.shared_functions) \
        and all(isinstance(f, ca.Function) for f in functions.values())


def _derivatives(solver: Any, names: dict) -> dict:
    """``{option: function}`` of the derivative functions ``solver`` has (an
    option such as a quasi-Newton Hessian leaves some out)."""
    out = {}
    for option, name in names.items():
        try:
            out[option] = solver.get_function(name)
        except RuntimeError:
            pass
    return out
