"""The active-set step built in a background thread while IPOPT solves
(methods/ccp_steps.py, ``prefetch_conic_step``): the same step as a build in
the caller's thread, the same answers from ``auto``, and a failed background
build that costs nothing but the time."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import scipy.sparse as sp

import belief_nlp as bn
from belief_nlp.methods import background, ccp_steps
from belief_nlp.model.cache import MEMORY
from belief_nlp.model.conic_form import conic_step

from conftest import ccp_problem, paper_multi_path_pair, switching_off_more

pytestmark = pytest.mark.skipif(background.cpus() < 2, reason="a background build needs a second CPU")


@pytest.fixture
def fresh(monkeypatch):
    """No step in memory or building, no disk cache; restored afterwards."""
    monkeypatch.setattr(ccp_steps, "disk_cache", lambda: None)
    saved = dict(MEMORY._d)
    background.wait_all()
    background.settle()
    MEMORY.clear()
    yield
    background.wait_all()
    background.settle()
    MEMORY.clear()
    MEMORY._d.update(saved)


def _same_step(a, b) -> None:
    """Every array of two ConicSteps equal, and their parameter maps equal at a random point."""
    for name, value in vars(a).items():
        other = getattr(b, name)
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(value, other, err_msg=name)
        elif sp.issparse(value):
            assert (value != other).nnz == 0, name
    assert a.A_shape == b.A_shape
    for x, y in zip(a.cones, b.cones):
        np.testing.assert_array_equal(x, y)
    p = np.random.default_rng(0).uniform(0.1, 1.0, a.fn.size1_in(0))
    for x, y in zip(a.fn(p), b.fn(p)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_background_step_equals_one_built_in_the_caller(fresh):
    sc, path = paper_multi_path_pair(steps_per_segment=2)
    model, _ = ccp_problem(sc, path)
    inline = conic_step(model.convex_form)
    built_in = []
    real = ccp_steps.conic_step

    def spy(form):
        built_in.append(threading.current_thread() is threading.main_thread())
        return real(form)

    ccp_steps.conic_step = spy
    try:
        assert ccp_steps.prefetch_conic_step(model)
        assert not ccp_steps.prefetch_conic_step(model)          # building: not twice
        step = ccp_steps.conic_step_of(model)
    finally:
        ccp_steps.conic_step = real
    assert built_in == [False]                                   # once, and not in the caller's thread
    _same_step(inline, step)
    assert not ccp_steps.prefetch_conic_step(model)              # in memory now


def test_no_background_build_when_switched_off(fresh, monkeypatch):
    sc, path = paper_multi_path_pair(steps_per_segment=2)
    model, _ = ccp_problem(sc, path)
    monkeypatch.setattr(ccp_steps, "PREFETCH", False)
    assert not ccp_steps.prefetch_conic_step(model)
    monkeypatch.setattr(ccp_steps, "PREFETCH", True)
    monkeypatch.setattr(ccp_steps, "disk_cache", lambda: object())   # a disk cache answers first calls
    assert not ccp_steps.prefetch_conic_step(model)
    assert not background._JOBS


def test_failed_background_build_is_built_again_in_the_caller(fresh):
    sc, path = paper_multi_path_pair(steps_per_segment=2)
    model, _ = ccp_problem(sc, path)
    real = ccp_steps.conic_step

    def fails_in_a_thread(form):
        if threading.current_thread() is not threading.main_thread():
            raise MemoryError("no room in the worker")
        return real(form)

    ccp_steps.conic_step = fails_in_a_thread
    try:
        assert ccp_steps.prefetch_conic_step(model)
        step = ccp_steps.conic_step_of(model)
    finally:
        ccp_steps.conic_step = real
    _same_step(real(model.convex_form), step)


def test_auto_first_call_gives_the_same_answer_with_the_step_built_beside_ipopt(fresh, monkeypatch):
    # paper-multi seed 0 at alpha 1, K = 20, the polish switching off up to 5x the floor:
    # IPOPT's answer is not stationary in S, so the CCP polish runs on the active-set
    # step (tests/test_nlp_stationary.py)
    switching_off_more(monkeypatch)
    sc = bn.load_scenario("paper-multi")
    ws = bn.warm_start(sc, bn.plan(sc, n_nodes=500, seed=0, noise="per_step").path, K=20)
    started = []
    real = ccp_steps.prefetch_conic_step
    monkeypatch.setattr(ccp_steps, "PREFETCH", False)
    alone = bn.smooth(sc, ws, method="auto", alpha=1.0)
    MEMORY.clear()
    monkeypatch.setattr(ccp_steps, "PREFETCH", True)
    import belief_nlp.methods.auto as auto
    monkeypatch.setattr(auto, "prefetch_conic_step", lambda model: started.append(real(model)) or started[-1])
    beside = bn.smooth(sc, ws, method="auto", alpha=1.0)
    assert started == [True] and not background._JOBS           # built beside IPOPT, then taken
    assert alone.stats["stages"] == beside.stats["stages"] == ["ipopt", "ccp polish"]
    assert beside.safe and beside.cost == alone.cost
    np.testing.assert_array_equal(beside.x, alone.x)
