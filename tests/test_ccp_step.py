"""The CCP step as a CVXPY problem: compiled once, DPP, open to users' own
constraints and to other solvers, cached on disk safely."""

from __future__ import annotations

import os
import pickle

import cvxpy as cp
import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.errors import ValidationError
from belief_nlp.methods.ccp import CHI2_MARGIN, compiled_step, usable_solvers
from belief_nlp.model import BeliefModel
from belief_nlp.model.cache import MEMORY, DiskCache, problem_key

from conftest import paper_multi_path_pair


@pytest.fixture(scope="module")
def small():
    return paper_multi_path_pair(steps_per_segment=2)          # K = 10


def test_ccp_subproblem_is_a_dpp_problem_ready_to_solve(small):
    sc, path = small
    prob = bn.ccp_subproblem(sc, path, alpha=1.0)
    assert isinstance(prob, cp.Problem) and prob.is_dpp() and prob.is_dcp()
    assert all(p.value is not None for p in prob.parameters())
    prob.solve(solver="CLARABEL")                       # Clarabel's own defaults
    assert prob.status in ("optimal", "optimal_inaccurate")
    value = prob.value
    prob.solve(solver="CLARABEL", equilibrate_enable=False, presolve_enable=False)   # the library's settings
    assert prob.value == pytest.approx(value, rel=1e-6)
    # about ten batched constraints, whatever K is
    assert len(prob.constraints) <= 13


def test_each_subproblem_is_its_own_problem(small):
    """Two calls give two problems: solving one leaves the other's answer alone."""
    sc, path = small
    a = bn.ccp_subproblem(sc, path, alpha=0.1)
    b = bn.ccp_subproblem(sc, path, alpha=1.0)
    assert a is not b and not set(map(id, a.parameters())) & set(map(id, b.parameters()))
    va = a.solve(solver="CLARABEL")
    vb = b.solve(solver="CLARABEL")
    assert va != pytest.approx(vb, rel=1e-3)
    assert a.solve(solver="CLARABEL") == pytest.approx(va, rel=1e-7)


def test_a_solved_subproblem_maps_back_to_a_safe_cheaper_path(small):
    """The first step's answer is a BeliefPath in SI units that the independent
    check finds safe and that costs no more than the warm start (CCP's descent)."""
    sc, path = small
    prob = bn.ccp_subproblem(sc, path, alpha=1.0)
    with pytest.raises(ValidationError, match="solve it first"):
        bn.ccp_subproblem_path(prob)
    prob.solve(solver="CLARABEL")
    step_path = bn.ccp_subproblem_path(prob)
    ws = bn.warm_start(sc, path)
    assert step_path.K == ws.K and bn.verify(sc, step_path).safe
    assert step_path.steering_cost(1.0) <= ws.path.steering_cost(1.0) + 1e-9
    with pytest.raises(ValidationError, match="ccp_subproblem"):
        bn.ccp_subproblem_path(cp.Problem(cp.Minimize(0)))


def test_the_api_tour_line_works_in_a_fresh_process(tmp_path):
    """README's API tour: ccp_subproblem(...).solve(solver=...) with no settings,
    in a process where nothing else ran; Clarabel and SCS reach one optimum."""
    import subprocess
    import sys

    code = (
        "import belief_nlp as bn\n"
        "sc = bn.load_scenario('paper-multi')\n"
        "planned = bn.plan(sc, n_nodes=200, seed=0, noise='per_step')\n"
        "prob = bn.ccp_subproblem(sc, planned.path, K=8, alpha=1.0)\n"
        "prob.solve(solver='CLARABEL')\n"
        "print(prob.status, float(prob.value))\n"
        "prob.solve(solver='SCS')\n"
        "print(prob.status, float(prob.value))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                         cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    (s1, v1), (s2, v2) = (line.split() for line in out.stdout.strip().splitlines()[-2:])
    assert s1 in ("optimal", "optimal_inaccurate") and s2 in ("optimal", "optimal_inaccurate")
    assert float(v2) == pytest.approx(float(v1), rel=1e-4)


def test_every_iteration_uses_the_one_compiled_problem(small):
    sc, path = small
    MEMORY.clear()
    res = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=4, active_set=False)
    assert res.stats["compile"] == "compiled"
    again = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=4, active_set=False)
    assert again.stats["compile"] == "memory"
    assert again.cost == pytest.approx(res.cost, rel=1e-10)
    # alpha is the step's parameter: another alpha re-uses the compiled problem
    other = bn.smooth(sc, path, method="ccp", alpha=0.1, max_iter=4, active_set=False)
    assert other.stats["compile"] == "memory" and other.safe and other.cost < other.initial_cost


def test_a_users_constraint_is_honoured_for_the_whole_run(small):
    """All means inside a box that the unconstrained answer leaves."""
    sc, path = small
    free = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=30)
    x_max = float(np.max(free.path.x[:, 0]))
    box = 0.5 * (x_max + float(np.max(path.x[:, 0]))) if x_max < np.max(path.x[:, 0]) else x_max - 0.01
    # the warm start satisfies it (its means are the path's); the free answer does not
    box = max(box, float(np.max(path.x[:, 0])))
    limit = min(box, x_max - 1e-3) if x_max - 1e-3 >= np.max(path.x[:, 0]) else None
    if limit is None:       # the free answer stays inside the start's box: bound the y coordinate instead
        y_min_free = float(np.min(free.path.x[1:-1, 1]))
        y_min_start = float(np.min(path.x[1:-1, 1]))
        limit_y = 0.5 * (y_min_free + y_min_start)
        assert y_min_free < limit_y <= y_min_start

        def cons(step):
            return [step.means()[1:-1, 1] >= limit_y]

        res = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=30, constraints=cons)
        assert np.min(res.path.x[1:-1, 1]) >= limit_y - 1e-7
    else:
        def cons(step):
            return [step.means()[:, 0] <= limit]

        res = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=30, constraints=cons)
        assert np.max(res.path.x[:, 0]) <= limit + 1e-7
    assert res.safe and res.cost <= res.initial_cost
    assert res.cost >= free.cost * (1 - 1e-6)          # a constrained optimum is no better


def test_hook_sees_each_step_with_parameters_set(small):
    sc, path = small
    seen = []

    def hook(step, it):
        seen.append((it, step.problem.is_dpp(), all(p.value is not None for p in step.problem.parameters())))

    res = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=3, hook=hook)
    assert [s[0] for s in seen] == list(range(1, res.nit + 1)) and all(s[1] and s[2] for s in seen)


def test_solvers_are_checked_before_any_work(small):
    sc, path = small
    usable = usable_solvers()
    assert "CLARABEL" in usable and "OSQP" not in usable
    for bad in ("FOO", "OSQP"):
        with pytest.raises(ValidationError) as exc:
            bn.smooth(sc, path, method="ccp", solver=bad)
        assert exc.value.field == "solver" and "CLARABEL" in str(exc.value)
    with pytest.raises(ValidationError) as exc:
        bn.smooth(sc, path, method="ccp", solver_options={"no_such_setting": 1})
    assert exc.value.field == "solver_options"


@pytest.mark.skipif("SCS" not in usable_solvers(), reason="SCS is not installed")
def test_another_installed_solver_runs_end_to_end():
    sc, path = paper_multi_path_pair(steps_per_segment=1)        # K = 5
    res = bn.smooth(sc, path, method="ccp", alpha=1.0, max_iter=2, solver="SCS",
                    solver_options={"eps_abs": 1e-7, "eps_rel": 1e-7})
    assert res.solver == "SCS" and res.safe and res.cost <= res.initial_cost
    assert res.nit >= 1 and res.history[1].solver_status.startswith("optimal")


def test_disk_cache_round_trip_and_refuses_foreign_entries(small, tmp_path):
    sc, path = small
    MEMORY.clear()
    cache = tmp_path / "cache"
    first = bn.smooth(sc, path, method="ccp", alpha=0.1, max_iter=2, cache_dir=cache, active_set=False)
    assert first.stats["compile"] == "compiled"
    entries = list(cache.glob("*.ccp.pkl"))
    assert len(entries) == 1 and oct(entries[0].stat().st_mode & 0o777) == "0o600"
    MEMORY.clear()
    second = bn.smooth(sc, path, method="ccp", alpha=0.1, max_iter=2, cache_dir=cache, active_set=False)
    assert second.stats["compile"] == "disk" and second.cost == pytest.approx(first.cost, rel=1e-9)
    # tampered: one byte changed -> ignored and rebuilt
    blob = bytearray(entries[0].read_bytes())
    blob[-10] ^= 0xFF
    entries[0].write_bytes(bytes(blob))
    MEMORY.clear()
    third = bn.smooth(sc, path, method="ccp", alpha=0.1, max_iter=2, cache_dir=cache, active_set=False)
    assert third.stats["compile"] == "compiled"
    # a pickle written by someone else (not signed with this folder's key) is never loaded
    model = BeliefModel(sc, first.path.K, 0.1)
    key = problem_key(model.data, CHI2_MARGIN, "CLARABEL")
    (cache / (key + ".ccp.pkl")).write_bytes(b"\0" * 32 + pickle.dumps({"evil": True}))
    assert DiskCache(cache).load(key) is None
    # a folder writable by others is not used
    os.chmod(cache, 0o777)
    assert DiskCache(cache).load(key) is None
    os.chmod(cache, 0o700)


def test_compiled_step_reports_where_it_came_from(small):
    sc, path = small
    MEMORY.clear()
    model = BeliefModel(sc, 10, 0.1)
    _, origin, _ = compiled_step(model)
    _, origin2, _ = compiled_step(BeliefModel(sc, 10, 0.1))
    assert (origin, origin2) == ("compiled", "memory")


def test_subproblem_after_a_ccp_run_of_the_same_model(small):
    """The compiled problem a CCP run solved (and cached) is the one a
    subproblem is copied from: the copy solves on its own and the run's
    problem keeps working (found: a deepcopy renamed the leaves the compiled
    chain is keyed by)."""
    sc, path = small
    bn.smooth(sc, path, method="ccp", alpha=0.1, max_iter=1)
    prob = bn.ccp_subproblem(sc, path, alpha=0.1)
    prob.solve(solver="CLARABEL")
    assert prob.status in ("optimal", "optimal_inaccurate")
    again = bn.smooth(sc, path, method="ccp", alpha=0.1, max_iter=2)
    assert again.nit == 2 and again.safe
