"""Every CCP step of a run is solved by Clarabel's defaults and by the
library's settings to the same optimum (issue 19, item 1): the step does not
depend on a solver's equilibration. Regression: adapted split weights used to
spread over 13 decades, and Clarabel's defaults failed on later steps."""

from __future__ import annotations

import warnings

import cvxpy as cp
import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.methods.ccp import RHO_BAND, SOLVER_DEFAULTS, _adapt_rho, initial_rho
from belief_nlp.model import BeliefModel


@pytest.fixture(scope="module")
def case():
    """paper-multi, per-step N = 500 plan of seed 1, K = 20 (a case whose later
    steps Clarabel's defaults failed before the weights were banded)."""
    sc = bn.load_scenario("paper-multi")
    planned = bn.plan(sc, n_nodes=500, seed=1, noise="per_step")
    return sc, bn.warm_start(sc, planned.path, K=20)


def _value(prob: cp.Problem, opts: dict) -> tuple[str, float | None]:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            prob.solve(solver="CLARABEL", warm_start=False, **opts)
    except cp.error.SolverError:
        return "error", None
    return str(prob.status), prob.value


def test_every_step_solves_with_clarabel_defaults_to_the_library_optimum(case):
    sc, ws = case
    rows = []

    def hook(step, it):
        rows.append((it, _value(step.problem, {}), _value(step.problem, SOLVER_DEFAULTS["CLARABEL"])))

    res = bn.smooth(sc, ws, method="ccp", alpha=0.1, max_iter=100, tol=1e-5, hook=hook)
    assert res.status == "converged" and len(rows) >= 10
    for it, (st_d, v_d), (st_l, v_l) in rows:
        assert st_d in ("optimal", "optimal_inaccurate"), (it, st_d)
        assert st_l in ("optimal", "optimal_inaccurate"), (it, st_l)
        assert v_d == pytest.approx(v_l, rel=1e-6, abs=1e-9), it


def test_adapted_weights_stay_in_their_band(case):
    """Steps that barely move a mean (or a certificate) would give ratios of
    1e-7 or 1e6; the weights stay within RHO_BAND of the first step's."""
    sc, ws = case
    model = BeliefModel(sc, ws.K, 0.1)
    prob_start = bn.smoother.context.SmoothingProblem(
        sc, ws, model, max_iter=1, tol=1e-4, time_limit=None, t0=0.0, solver=None, solver_options={},
        progress=False, keep_iterates=False, callback=None, method="ccp")
    z = prob_start.start
    rho0 = initial_rho(model, z)
    z_new = z.copy()
    z_new.x[1:-1] += 1e-12                      # means barely move, certificates move a lot
    z_new.lam = z.lam * 3.0 + 1.0
    rho = rho0.copy()
    for _ in range(6):                          # each step may move a weight 10x; the band caps the drift
        rho, _ = _adapt_rho(model, z, z_new, rho, rho, rho0)
    assert np.all(rho >= rho0 / RHO_BAND * (1 - 1e-12)) and np.all(rho <= rho0 * RHO_BAND * (1 + 1e-12))
    assert np.any(rho <= rho0 / RHO_BAND * (1 + 1e-12))     # the drift reached the band
