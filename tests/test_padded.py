"""IPOPT's solver padded with one free variable (methods/nlp_padded.py)."""

from __future__ import annotations

import re

import casadi as ca
import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.methods import ipopt as ipopt_method
from belief_nlp.methods.nlp_backend import NLPBackend
from belief_nlp.methods.nlp_engine import clear_cache
from belief_nlp.methods.nlp_padded import DERIVATIVES, PaddedSolver, pads
from belief_nlp.model import BeliefModel
from belief_nlp.model.nlp_form import build_nlp

_ZERO_TRIAL = re.compile(r"Solving system with delta_x=0\.000000e\+00")


def _solve(make, nlp, z, log, given=None):
    opts = {**ipopt_method.DEFAULT_IPOPT_OPTIONS, **ipopt_method.LOGCHOL_IPOPT_OPTIONS, "tol": 1e-8,
            "print_level": 0, "output_file": str(log), "file_print_level": 8}
    solver = make("s", "ipopt", {"x": nlp.z, "p": nlp.p, "f": nlp.f, "g": nlp.g},
                  {"ipopt": opts, "print_time": False, **(given or {})})
    sol = solver(x0=nlp.pack(z), p=nlp.anchor(z), lbx=nlp.lbz, ubx=nlp.ubz, lbg=nlp.lbg, ubg=nlp.ubg)
    return solver, sol, log.read_text()


def test_ipopt_declares_the_padded_hessian_degenerate_and_skips_the_zero_trials(small_start, tmp_path):
    """IPOPT's log (print level 8): on the plain NLP every iteration first
    factorises with delta_w = 0; on the padded one its degeneracy test says
    "Dh" (structurally degenerate Hessian) and no zero trial follows. Both
    reach the same optimum, and the padded solver answers on the NLP's own
    variables (x and lam_x of the NLP's length)."""
    sc, ws = small_start
    model = BeliefModel(sc, ws.K, 1.0)
    z = model.tighten(model.from_path(ws.path, ws.lam))
    nlp = build_nlp(model, "logchol")
    plain, ref, log_plain = _solve(ca.nlpsol, nlp, z, tmp_path / "plain.log")
    padded, sol, log_padded = _solve(PaddedSolver, nlp, z, tmp_path / "padded.log")
    assert plain.stats()["success"] and padded.stats()["success"]
    n = int(nlp.z.shape[0])
    assert sol["x"].shape == (n, 1) and sol["lam_x"].shape == (n, 1)
    assert float(sol["f"]) == pytest.approx(float(ref["f"]), rel=1e-7)
    np.testing.assert_allclose(np.asarray(sol["x"]), np.asarray(ref["x"]), rtol=1e-4, atol=1e-5)
    its_plain, its_padded = plain.stats()["iter_count"], padded.stats()["iter_count"]
    assert "Dh" not in log_plain and len(_ZERO_TRIAL.findall(log_plain)) >= its_plain
    assert "Dh" in log_padded
    after = log_padded.split("Dh", 1)[1]
    assert its_padded > 5 and not _ZERO_TRIAL.findall(after)
    # the derivative functions it gives are the NLP's own (x of its length), and
    # solvers given them, padded or not, reach the same optimum (the polish's route)
    shared = {k: padded.get_function(v) for k, v in DERIVATIVES.items()}
    assert all(f.size1_in(0) == n for f in shared.values())
    for make, name in ((PaddedSolver, "again.log"), (ca.nlpsol, "plain_given.log")):
        solver, other, _ = _solve(make, nlp, z, tmp_path / name, shared)
        assert solver.stats()["success"] and float(other["f"]) == pytest.approx(float(ref["f"]), rel=1e-7)


def test_cold_solves_are_padded_and_warm_started_ones_not():
    """The first stage (cold) is padded; the polish and a resumed stage
    (IPOPT's warm_start_init_point) are not: next to a minimiser the zero
    trial is what converges fast."""
    assert pads(ipopt_method.LOGCHOL_IPOPT_OPTIONS) == 1
    assert pads(ipopt_method.POLISH_IPOPT_OPTIONS) == 0 and pads(ipopt_method.RESUME_IPOPT_OPTIONS) == 0


def test_the_method_on_the_padded_solver_answers_as_on_the_plain_one(small_start, monkeypatch):
    """Method "ipopt" (both stages, the recorder, the polish from the first
    stage's multipliers, the stationarity verdict) padded and not: the same
    optimum, both verified."""
    sc, ws = small_start
    runs = []
    for pad in (True, False):
        clear_cache()
        if not pad:
            monkeypatch.setattr(ipopt_method.IpoptBackend, "pads", NLPBackend.pads)
            monkeypatch.setattr(ipopt_method.IpoptBackend, "nlpsol", NLPBackend.nlpsol)
        res = bn.smooth(sc, ws, alpha=1.0, method="ipopt", cache=False)
        assert res.success and bn.verify(sc, res.path).safe
        runs.append(res)
    clear_cache()
    assert runs[0].cost == pytest.approx(runs[1].cost, rel=1e-6)
    assert runs[0].stats["sensing_stationary"] == runs[1].stats["sensing_stationary"]
