"""Every registered smoothing method -- the built-ins and a toy one added the
way a user adds one (tests/toy_method.py, one file) -- passes one contract."""

from __future__ import annotations

import importlib

import pytest

import belief_nlp as bn
from belief_nlp.smoother.conformance import check_method
from belief_nlp.smoother.registry import unregister


@pytest.fixture(scope="module", autouse=True)
def _toy_registered():
    """Import the toy method's file (importing registers it), for this module only."""
    toy = importlib.import_module("toy_method")
    bn.register_method(toy.METHOD, replace=True)
    yield
    unregister("sensing_trim")


def test_the_registry_lists_the_builtins_and_the_toy_method():
    names = bn.available_methods()
    assert names[:4] == ["auto", "ccp", "ipopt", "sqp"] and "sensing_trim" in names      # the default first
    assert bn.get_method("ccp").max_iter == 50 and bn.get_method("ipopt").max_iter == 3000


@pytest.mark.parametrize("name", ["ccp", "ipopt", "auto", "sqp", "sensing_trim"] + (["fatrop"] if "fatrop" in bn.available_methods() else []))
def test_conformance(name):
    check_method(name)


def test_a_plain_callable_is_a_method():
    """smooth(method=fn) as scipy.optimize.minimize(method=fn): fn(problem, **options)."""
    def polish(problem, step=0.5):
        z = problem.start.copy()
        z.S[1:] *= 1 - step
        chk = problem.check(problem.model.tighten(z))
        ok = chk.safe and problem.model.cost(chk.point)[0] < problem.cost0
        c = problem.model.cost(chk.point if ok else problem.start)
        problem.record(bn.IterationRecord(1, *c, accepted=ok), chk.point if ok else None)
        return bn.Outcome("converged", "one trim")

    check_method(polish)
    sc, path = bn.smoother.conformance.small_problem()
    res = bn.smooth(sc, path, method=polish, step=0.25)
    assert res.method == "polish" and res.cost <= res.initial_cost


def test_a_method_that_reports_success_above_the_start_is_corrected():
    """The driver never reports success above the warm start, whatever a method says."""
    def liar(problem):
        z = problem.start.copy()
        z.S[1:] *= 10.0                                  # safe (more sensing), but dearer
        return bn.Outcome("converged", "I converged", point=problem.model.tighten(z))

    sc, path = bn.smoother.conformance.small_problem()
    res = bn.smooth(sc, path, method=liar)
    assert not res.success and res.status == "above_start"
    assert res.cost == pytest.approx(res.initial_cost)


def test_a_converged_answer_within_tol_above_an_optimal_start_keeps_converged():
    """A start that is already optimal (a re-plan from the planned belief):
    a converged answer no lower, within tol (relative) of it, returns the
    start as converged; beyond tol it is still "above_start"."""
    def nudge(problem):
        z = problem.start.copy()
        z.S[1:] *= 1.001                                 # safe (more sensing), a little dearer
        return bn.Outcome("converged", "converged", point=problem.model.tighten(z))

    sc, path = bn.smoother.conformance.small_problem()
    for tol, status in ((0.5, "converged"), (1e-9, "above_start")):
        res = bn.smooth(sc, path, method=nudge, tol=tol)
        assert res.status == status and res.success == (status == "converged")
        assert res.cost == res.initial_cost                    # the start, never the dearer answer
        assert ("within tol = 0.5" in res.message) == (status == "converged")


def test_a_method_answer_that_is_unsafe_is_never_returned():
    def reckless(problem):
        z = problem.start.copy()
        z.S[1:] = 0.0                                    # no sensing: the ellipses grow into obstacles
        z.x[1:] = z.x[1:] * 0 + z.x[:1]                  # and every mean at the start
        return bn.Outcome("converged", "done", point=problem.model.tighten(z))

    sc, path = bn.smoother.conformance.small_problem()
    res = bn.smooth(sc, path, method=reckless)
    assert not res.success and res.status == "infeasible_iterate" and res.safe


def test_cli_lists_registered_methods_without_edits(capsys):
    """The toy method was registered by its own file only; the CLI lists it and
    accepts it as --method."""
    from belief_nlp.cli import build_parser, main

    assert main(["methods"]) == 0
    out = capsys.readouterr().out
    assert "ccp" in out and "ipopt" in out and "sensing_trim" in out and "shrink" in out
    args = build_parser().parse_args(["smooth", "paper-multi", "--method", "sensing_trim"])
    assert args.method == "sensing_trim"
