"""IPOPT's solver of an NLP padded with one free variable that nothing reads.

IPOPT keeps the inertia of its Newton matrix right by adding delta_w I to
the Hessian (docs/numerics.md, "IPOPT iterations and K"). Each iteration it
first factorises with delta_w = 0 unless its degeneracy test, in the first
iterations, found the matrix singular at delta_w = 0 ("structurally
degenerate Hessian", IpPDPerturbationHandler.cpp): then every iteration
starts from a third of the last delta_w. Our Hessian is not singular, but
its negative curvature (the Kalman rows in the lifted factors M_k) needs a
correction in 92 % of the iterations (158 of 171 on paper-multi at K = 40,
alpha 1: 409 factorisations), so the delta_w = 0 trial is a factorisation
wasted nearly every time.

A free variable that neither the cost nor any row reads makes the matrix
singular at delta_w = 0 by construction, so IPOPT's own test declares the
Hessian degenerate after its first three iterations and skips those trials;
the variable's step is 0 and it stays at 0. Measured on the issue-21
protocol (docs/numerics.md, "One free variable more"): per-case wall 0.84x
at K = 40 and 0.88x at K = 20 for ``auto`` (0.97x at K = 80), every answer
verified, 183 of 184 costs the same (one other local optimum, +0.3 %).

A warm-started solve (the polish, a resumed stage: IPOPT's
``warm_start_init_point``) starts next to a minimiser, where the zero trial
is what converges fast: it is not padded (:func:`pads`).

:class:`PaddedSolver` is called and asked as the nlpsol it wraps, on the
NLP's own variables: it appends the variable to x0, lbx, ubx and lam_x0,
and drops it from x and lam_x; the derivative functions it is given and
the ones it gives (``get_function``: another stage's solver on the same
graph is given them) are the NLP's own, padded and unpadded by cheap
wrappers.
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

__all__ = ["PaddedSolver", "pads"]

#: the derivative functions of a nlpsol (option name: the solver's function name)
DERIVATIVES = {"grad_f": "nlp_grad_f", "jac_g": "nlp_jac_g", "hess_lag": "nlp_hess_l"}


def pads(options: dict) -> int:
    """Free variables an IPOPT solver with plug-in ``options`` is padded
    with: 1 for a cold start, 0 for a warm-started one."""
    return 0 if str(options.get("warm_start_init_point", "no")).lower() == "yes" else PaddedSolver.pad


class PaddedSolver:
    """``ca.nlpsol(name, plugin, nlp + one free variable, options)`` read on ``nlp``'s variables."""

    pad = 1

    def __init__(self, name: str, plugin: str, nlp: dict, options: dict):
        z = nlp["x"]
        self.n = int(z.shape[0])
        free = type(z).sym("belief_nlp_pad", self.pad)
        # given derivative functions on the padded x: the free variable's entries are zeros
        given = {k: _resized(options[k], k, self.n + self.pad) for k in DERIVATIVES if k in options}
        self.solver = ca.nlpsol(name, plugin, {**nlp, "x": ca.vertcat(z, free)}, {**options, **given})
        self._own: dict = {}

    def __call__(self, **args: Any) -> dict:
        args = dict(args)
        for key, value in (("x0", 0.0), ("lbx", -np.inf), ("ubx", np.inf), ("lam_x0", 0.0)):
            if key in args:
                args[key] = np.append(np.asarray(args[key], float).ravel(), np.full(self.pad, value))
        sol = dict(self.solver(**args))
        for key in ("x", "lam_x"):
            if key in sol:
                sol[key] = sol[key][:self.n]
        return sol

    def stats(self) -> dict:
        return self.solver.stats()

    def get_function(self, name: str) -> ca.Function:
        """The solver's function ``name`` on the NLP's own variables (the
        derivative functions; others as the padded solver has them)."""
        if name not in self._own:
            fn = self.solver.get_function(name)
            option = next((k for k, v in DERIVATIVES.items() if v == name), None)
            self._own[name] = fn if option is None else _resized(fn, option, self.n)   # the free variable at 0
        return self._own[name]


#: which dimensions of each derivative function's last output run over x (rows, columns)
_X_DIMS = {"grad_f": (True, False), "jac_g": (False, True), "hess_lag": (True, True)}


def _resized(fn: ca.Function, option: str, n: int) -> ca.Function:
    """``fn`` (option ``option``, x its first input) on an x of n entries:
    x cut or padded with zeros to fn's, the last output's x dimensions cut
    or padded with zeros to n."""
    ins = [ca.MX.sym(fn.name_in(i), *((n, 1) if i == 0 else fn.sparsity_in(i).shape)) for i in range(fn.n_in())]
    outs = fn.call([_fit(ins[0], fn.sparsity_in(0).shape[0], 1)] + ins[1:])
    rows, cols = _X_DIMS[option]
    last = outs[-1]
    last = _fit(last, n if rows else last.shape[0], n if cols else last.shape[1])
    # the gradient dense: the plug-in reads its nonzeros as the dense vector (a
    # structural zero there left the free variable's entry stale: Diverging_Iterates)
    outs[-1] = ca.densify(last) if option == "grad_f" else last
    return ca.Function(fn.name(), ins, outs, fn.name_in(), fn.name_out())


def _fit(e: ca.MX, rows: int, cols: int) -> ca.MX:
    """``e`` cut, or padded with structural zeros, to rows x cols."""
    e = e[:min(rows, e.shape[0]), :min(cols, e.shape[1])]
    if e.shape[0] < rows:
        e = ca.vertcat(e, ca.MX(rows - e.shape[0], e.shape[1]))
    if e.shape[1] < cols:
        e = ca.horzcat(e, ca.MX(e.shape[0], cols - e.shape[1]))
    return e
