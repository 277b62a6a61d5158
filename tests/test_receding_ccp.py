"""Re-plans after executed steps with method "ccp": the conic step built for
the longer horizon, still in memory, solved with those steps frozen
(belief_nlp.model.conic_prefix), checked end to end against re-plans that
build the shorter horizon's own step."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.methods.ccp_steps import CHI2_MARGIN, conic_step_of
from belief_nlp.model import BeliefModel
from belief_nlp.model.cache import MEMORY, problem_key
from belief_nlp.model.conic_prefix import FrozenConic

from conftest import paper_multi_path_pair

KW = {"method": "ccp", "alpha": 1.0}


@pytest.fixture(scope="module")
def ccp10():
    """paper-multi on the hand route (K = 10) and CCP's answer."""
    sc, path = paper_multi_path_pair(2)
    return sc, bn.smooth(sc, bn.warm_start(sc, path), **KW)


def _moved(sc, previous, rng) -> bn.Scenario:
    """The robot after one executed step, near the plan's belief there."""
    return sc.with_options(x0=previous.path.x[1] + 5e-4 * rng.uniform(-1, 1, 2), P0=0.7 * previous.path.P[1])


def _built(sc, K: int) -> None:
    """The K-step conic step in memory (another test may have cleared it)."""
    conic_step_of(BeliefModel(sc, K, 1.0))


def _own_step(sc, K: int):
    """The shorter horizon's own conic step in memory, or None."""
    return MEMORY.get(problem_key(BeliefModel(sc, K, 1.0).data, CHI2_MARGIN, "CLARABEL-direct"))


def test_a_ccp_loop_solves_the_longer_step_frozen(ccp10):
    """Two executed steps, one at a time: each re-plan runs on the K = 10
    step (the shorter horizons' own steps are never built), answers as the
    re-plan that builds its horizon (cost to 1e-6), verified, and its state
    counts the frozen steps."""
    sc, previous = ccp10
    assert previous.resume == {"offset": 0}
    MEMORY.clear()                     # (other tests may have built the shorter horizons)
    _built(sc, previous.path.K)
    rng = np.random.default_rng(0)
    K = previous.path.K
    chain, moved_all = [previous], []
    for step in range(1, 3):
        moved = _moved(sc, chain[-1], rng)
        r = bn.replan(moved, chain[-1], advance=1, **KW)
        assert r.stats["frozen"] == step and r.resume == {"offset": step}
        assert _own_step(moved, K - step) is None                 # nothing built for the shorter horizon
        assert r.status == "converged" and bn.verify(moved, r.path).safe and r.cost <= r.initial_cost
        chain.append(r)
        moved_all.append(moved)
    for step, (moved, r) in enumerate(zip(moved_all, chain[1:]), 1):
        MEMORY.clear()
        ref = bn.replan(moved, dataclasses.replace(chain[step - 1], resume=None), advance=1, **KW)
        assert ref.stats["frozen"] == 0 and ref.resume == {"offset": 0}
        assert r.cost == pytest.approx(ref.cost, rel=1e-6)


def test_a_relaxed_replan_solves_the_longer_step_frozen(ccp10):
    """A start held to its own level (start_confidence) after executed
    steps: the relief is the longer step's parameter at the transition after
    the prefix, so the re-plan runs on the K = 10 step, verified at its
    levels, at the cost of the re-plan that builds its horizon (1e-6)."""
    sc, previous = ccp10
    MEMORY.clear()
    _built(sc, previous.path.K)
    rng = np.random.default_rng(5)
    for step in range(1, 3):
        moved = _moved(sc, previous, rng).with_options(start_confidence=0.7)
        r = bn.replan(moved, previous, advance=1, **KW)
        assert r.stats["frozen"] == step and _own_step(moved, previous.path.K - 1) is None
        assert r.status == "converged" and bn.verify(moved, r.path).safe and r.cost <= r.initial_cost
        ref = bn.replan(moved, dataclasses.replace(previous, resume=None), advance=1, **KW)
        assert ref.stats["frozen"] == 0 and r.cost == pytest.approx(ref.cost, rel=1e-6)
        previous = r


def test_when_the_frozen_step_fails_ccp_goes_on_with_the_horizons_own(ccp10, monkeypatch):
    """The frozen step has no CVXPY cascade behind it: when neither of its
    answers comes, the run goes on from its last point with the shorter
    horizon's own step (built), and answers."""
    sc, previous = ccp10
    moved = _moved(sc, previous, np.random.default_rng(1))
    _built(sc, previous.path.K)
    monkeypatch.setattr(FrozenConic, "solve", lambda self, *a, **k: ("failed (test)", None, 0.0, 0))
    r = bn.replan(moved, previous, advance=1, **KW)
    assert r.stats["frozen_failed"]["status"] == "solver_failed" and r.stats["frozen"] == 0
    assert r.status == "converged" and bn.verify(moved, r.path).safe and r.cost < r.initial_cost
    assert _own_step(moved, previous.path.K - 1) is not None


def test_states_go_to_the_methods_that_take_them(ccp10):
    """A CCP state is not IPOPT's: a re-plan with ``ipopt`` from a CCP answer
    starts from the path alone; a bad state given to ccp is our error."""
    sc, previous = ccp10
    moved = _moved(sc, previous, np.random.default_rng(2))
    r = bn.replan(moved, previous, advance=1, method="ipopt", alpha=1.0)
    assert r.stats["resumed"] == "no" and r.status == "converged"
    for bad in ({"offset": -1}, {"offset": True}, {"z": np.zeros(3)}, "1"):
        with pytest.raises(bn.ValidationError) as err:
            bn.smooth(moved, r.path, resume=bad, **KW)
        assert err.value.field == "resume"
