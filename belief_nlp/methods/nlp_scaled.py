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
substitution), its bounds, packing and cost parts in y. Its solver is built
by :func:`.nlp_build.solver_of` as any other (its own memory-cache key; its
derivative functions shared, and kept in the disk cache under the scaled
graph's hash, compiled on request, as the unscaled graph's).
"""

from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np

from ..model.nlp_form import NLPProblem

__all__ = ["scaled"]


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
    start = ca.SX.sym("start", nlp.margins.size1_in(1))
    margins = ca.Function("margins", [y, start], nlp.margins(Dy, start), ["z", "start"], ["collision", "target"])
    pack, unpack_with, without = nlp.pack, nlp.unpack_with, nlp.without_sensing
    out = dataclasses.replace(nlp, z=y, f=f, g=g, lbz=nlp.lbz / D, ubz=nlp.ubz / D, parts=parts, margins=margins,
                              pack=lambda lay: pack(lay) / D,
                              unpack_with=lambda yv, model: unpack_with(np.asarray(yv, float).ravel() * D, model),
                              info={**nlp.info, "variable_scale": D}, _view=None, graph=None)

    def without_sensing(lay, floor: float, slack: float = 0.1):
        z0, lbz, ubz = without(lay, floor, slack)
        return z0 / D, lbz / D, ubz / D

    out.without_sensing = without_sensing      # type: ignore[method-assign]
    return out
