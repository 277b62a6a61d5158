"""The NLP with the path's means scaled: z = D y with D = ``scale`` on the
means and 1 elsewhere, for the "logchol" stage of method "ipopt"
(option ``scale_means``; docs/numerics.md, "K = 80: continuation and sensing
pattern (session 10)").

Why: IPOPT corrects the inertia of its Newton matrix by adding delta_w I
(delta_w ~ 1e-3 .. 1e-2.5 in 70-80 % of the stage's iterations), the same
shift for every variable. The path's smooth modes (blocks of means moving
together) have a curvature that falls with K, so at K = 80 the shift damps
their Newton steps to a small fraction and the stage crawls for 1000+
iterations. In y the means' block of the Hessian is ``scale``^2 times larger
and the same shift damps it ``scale``^2 times less; the optimum, the other
variables and the constraints are unchanged (the same points in x).

The scaled NLP is the graph's own f and g with z replaced by D y (one
substitution), its bounds, packing and cost parts in y; the solver derives
its derivatives on it (no sharing with the unscaled graph's, which the
polish uses); with the disk cache on they are kept there under the scaled
graph's hash. Its solvers are kept in the engine's memory cache under their
own key.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import casadi as ca
import numpy as np

from ..errors import ValidationError
from ..model.cache import disk_cache, problem_key
from ..model.nlp_form import NLPProblem
from ..smoother.context import SmoothingProblem
from .nlp_backend import NLPBackend
from .nlp_build import _CACHE, _complete, _derivatives, _derivatives_key, _nlp
from .nlp_recorder import Recorder

__all__ = ["scaled", "scaled_solver_of"]


def scaled(nlp: NLPProblem, scale: float) -> NLPProblem:
    """``nlp`` in y, z = D y (D: ``scale`` on the means, 1 elsewhere); its
    ``info["variable_scale"]`` is D (lam_x of the scaled NLP divided by D are
    the multipliers of ``nlp``'s bounds)."""
    nX = nlp.info["sensing_offset"]            # the means come first: K x d
    D = np.ones(int(nlp.z.shape[0]))
    D[:nX] = float(scale)
    y = ca.SX.sym("y", nlp.z.shape[0])
    Dy = ca.DM(D) * y
    f, g = ca.substitute([nlp.f, nlp.g], [nlp.z], [Dy])
    parts = ca.Function("parts", [y, nlp.p], nlp.parts(Dy, nlp.p), ["z", "p"],
                        ["control", "information", "regulariser"])
    margins = ca.Function("margins", [y], nlp.margins(Dy), ["z"], ["collision", "target"])
    pack, unpack, without = nlp.pack, nlp.unpack, nlp.without_sensing
    out = dataclasses.replace(nlp, z=y, f=f, g=g, lbz=nlp.lbz / D, ubz=nlp.ubz / D, parts=parts, margins=margins,
                              pack=lambda lay: pack(lay) / D,
                              unpack=lambda yv: unpack(np.asarray(yv, float).ravel() * D),
                              info={**nlp.info, "variable_scale": D}, _view=None, graph=None)

    def without_sensing(lay, floor: float, slack: float = 0.1):
        z0, lbz, ubz = without(lay, floor, slack)
        return z0 / D, lbz / D, ubz / D

    out.without_sensing = without_sensing      # type: ignore[method-assign]
    return out


def scaled_solver_of(problem: SmoothingProblem, backend: NLPBackend, opts: dict, formulation: str, margin: float,
                     regularisation: float, floor: float, candidates: int, cache: bool,
                     scale: float) -> tuple[NLPProblem, Any, Recorder, str]:
    """As :func:`.nlp_build.solver_of`, on the NLP scaled by :func:`scaled`."""
    floor_key = floor if formulation == "logchol" else None
    key = problem_key(problem.model.data, margin, f"{backend.plugin}:{formulation}:{regularisation}:{floor_key}:"
                                                  f"scale_means={float(scale)!r}:{sorted(opts.items())!r}")
    entry = _CACHE.get(key) if cache else None
    if entry is not None:
        return (*entry, "memory")
    view, _ = _nlp(problem, formulation, margin, regularisation, floor, cache)
    nlp = scaled(view, scale)
    # IPOPT's derivative functions of the scaled graph from the disk cache
    # (when on), under the hash of that graph as for the unscaled one
    disk = disk_cache() if cache and backend.shared_functions else None
    given, name = {}, None
    if disk is not None:
        name = _derivatives_key(nlp, backend)
        loaded = disk.load(name, kind="nlp")
        if _complete(loaded, backend):
            given, disk = loaded, None
    recorder = Recorder(nlp, keep=candidates, bar=None, stall=0)
    recorder.log_path = backend.log_file()
    try:
        solver = backend.nlpsol(f"belief_nlp_{backend.plugin}_scaled", {"x": nlp.z, "p": nlp.p, "f": nlp.f, "g": nlp.g},
                                {**backend.nlpsol_options(opts, recorder.log_path), **backend.structure_options(nlp),
                                 **given, "print_time": False, "iteration_callback": recorder, "error_on_fail": False,
                                 "show_eval_warnings": False})
    except RuntimeError as exc:  # bad option names or values
        raise ValidationError("solver_options",
                              f"{backend.name} refused them: {str(exc).splitlines()[-1][:200]}") from None
    if disk is not None:
        functions = _derivatives(solver, backend.shared_functions)
        if _complete(functions, backend):
            disk.save(name, functions, kind="nlp")
    if cache:
        _CACHE.put(key, (nlp, solver, recorder))
    return nlp, solver, recorder, "built (scaled means" + (", derivatives from disk)" if given else ")")
