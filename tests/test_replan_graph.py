"""Re-plans of the NLP methods that take no initial multipliers (fatrop,
Uno's SQP) after executed steps: solved on the last answer's graph with
those steps frozen, from the re-anchored path, so nothing is built.

Checked against the frozen stage-ordered form being the shorter problem's
own form term by term, and end to end against the re-plan that builds the
shorter horizon from the same warm start.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.methods import nlp_resume
from belief_nlp.model import BeliefModel
from belief_nlp.model.nlp_form import build_nlp
from belief_nlp.model.nlp_prefix import frozen
from belief_nlp.model.ocp_form import build_ocp

from conftest import assert_frozen_is_shorter, paper_multi_path_pair

METHODS = [m for m in ("sqp", "fatrop") if m in bn.available_methods()]


@pytest.fixture(scope="module")
def hand10():
    """paper-multi on the hand route (K = 10)."""
    return paper_multi_path_pair(2)


def _moved(sc, path, step: int, rng) -> bn.Scenario:
    """The robot after ``step`` executed steps: near the plan's belief there,
    the covariance smaller (a measurement went well), the mean moved up to 0.5 mm."""
    return sc.with_options(x0=path.x[step] + 5e-4 * rng.uniform(-1, 1, 2), P0=0.7 * path.P[step])


@pytest.mark.parametrize("offset, relaxed", [(1, False), (3, False), (2, True)])
def test_the_frozen_stage_form_is_the_shorter_problems_form(hand10, offset, relaxed):
    """fatrop's stage-ordered form of the K-step NLP with its first steps
    frozen has, at perturbed points of the shorter problem, the margins,
    cost parts and rows against bounds of the shorter problem's own form
    (also with the start held to its own level: the relief on the bounds);
    its stage structure is the longer form's (the solver built for it
    solves it), and a new start belief moves its fixed variables."""
    sc, path = hand10
    K = path.K
    ws0 = bn.warm_start(sc, path)
    moved = _moved(sc, ws0.path, offset, np.random.default_rng(offset))
    if relaxed:
        moved = moved.with_options(start_confidence=0.7)
    long_model, short_model = BeliefModel(sc, K, 1.0), BeliefModel(moved, K - offset, 1.0)
    long_form = build_ocp(build_nlp(long_model, "logchol", floor=1e-3))
    view = frozen(long_form, short_model, offset)
    short = build_ocp(build_nlp(short_model, "logchol", floor=1e-3))
    assert (view.N, view.nx, view.nu, view.ng) == (long_form.N, long_form.nx, long_form.nu, long_form.ng)
    assert view.z is long_form.z and view.g is long_form.g
    ws = bn.warm_start(moved, bn.reanchor(moved, ws0.path, advance=offset), sensing="path")
    z0 = short_model.tighten(short_model.from_path(ws.path, ws.lam))
    for _, zv, _, _ in assert_frozen_is_shorter(view, short, short_model, z0, np.random.default_rng(7)):
        assert np.all((zv >= view.lbz) & (zv <= view.ubz))          # the frozen variables at their values
    # the gap rows stay equalities (fatrop needs them); the frozen steps' own rows are free
    gap_rows = np.setdiff1d(np.arange(view.lbg.size), view.source_rows)
    assert np.all(view.lbg[gap_rows] == 0) and np.all(view.ubg[gap_rows] == 0)
    other = sc.with_options(x0=ws0.path.x[offset] + np.array([1e-3, 0.0]), P0=ws0.path.P[offset])
    again = view.for_model(BeliefModel(other, K - offset, 1.0))
    fixed = np.flatnonzero(again.lbz == again.ubz)
    assert fixed.size == np.flatnonzero(view.lbz == view.ubz).size
    assert not np.allclose(again.lbz[fixed], view.lbz[fixed])


@pytest.mark.parametrize("method", METHODS)
def test_a_receding_loop_builds_nothing_and_answers_as_the_built_horizon(hand10, method):
    """Three executed steps, one at a time: each re-plan is solved on the
    K = 10 graph (the first builds its solver with the backend's resume
    options, if it has any; the later ones build nothing) and gives the answer of the re-plan that
    builds its shorter horizon from the same warm start (the same local
    optimum to the solver's accuracy), verified, not above its warm start."""
    sc, path = hand10
    kw = {"method": method, "alpha": 1.0, "max_iter": 3000}
    previous = bn.smooth(sc, bn.warm_start(sc, path), **kw)
    assert previous.resume is not None and not nlp_resume.has_duals(previous.resume)
    rng = np.random.default_rng(0)
    for step in range(1, 4):
        moved = _moved(sc, previous.path, 1, rng)
        r = bn.replan(moved, previous, advance=1, **kw)
        ref = bn.replan(moved, dataclasses.replace(previous, resume=None), advance=1, **kw)
        assert r.stats["resumed"] == "graph" and ref.stats["resumed"] == "no"
        # the K = 10 graph's solver with the backend's resume options: built once, by the first
        assert r.stats["build"] == "memory" or step == 1
        assert ref.stats["build"] != "memory"
        assert r.safe and bn.verify(moved, r.path).safe and r.cost <= r.initial_cost
        assert r.path.K == path.K - step and r.resume["offset"] == step
        np.testing.assert_allclose(r.path.x[0], moved.x0, rtol=1e-15, atol=0)
        if r.status == ref.status == "converged":
            # the same local optimum to the solver's accuracy: Uno's to 1e-5; fatrop stops up to
            # 0.15-1 % above IPOPT's optimum at its tolerance (docs/numerics.md, "fatrop"), and two
            # of its converged answers from one start differed by 9e-4 once (a clean-clone CI run)
            assert r.cost == pytest.approx(ref.cost, rel=1e-5 if method == "sqp" else 1e-2), \
                (r.stats["attempts"], ref.stats["attempts"])
        previous = r


@pytest.mark.parametrize("method", METHODS)
def test_a_state_without_multipliers_is_not_ipopts(hand10, method):
    """The state of a solver that takes no multipliers does not fit IPOPT's
    resume (another plug-in): IPOPT builds the horizon and answers."""
    sc, path = hand10
    previous = bn.smooth(sc, bn.warm_start(sc, path), method=method, alpha=1.0)
    moved = _moved(sc, previous.path, 1, np.random.default_rng(3))
    r = bn.replan(moved, previous, advance=1, method="ipopt", alpha=1.0)
    assert r.stats["resumed"] == "does not fit" and r.safe and bn.verify(moved, r.path).safe


def test_the_resume_check_takes_a_bare_state_only_without_a_polish():
    bare = nlp_resume.state("fatrop", "k", 1e-2, np.zeros(0), None, 2)
    assert nlp_resume.check(bare) is None and not nlp_resume.has_duals(bare)
    full = nlp_resume.state("ipopt", "k", 1e-2, np.ones(3), (np.ones(3), np.ones(2)),
                            polish=(np.ones(3), (np.ones(3), np.ones(2))))
    assert nlp_resume.check(full) is None and nlp_resume.has_duals(full)
    assert nlp_resume.check({**bare, "polish": full["polish"]}) is not None
    assert nlp_resume.check({**full, "lam_g": None}) is not None          # one multiplier without the other


@pytest.mark.skipif("fatrop" not in METHODS, reason="this CasADi build has no fatrop plug-in")
def test_fatrops_graph_replan_takes_its_resume_options_unless_the_user_sets_them(hand10, monkeypatch):
    """The first stage of a graph re-plan is built with fatrop's resume
    options (a small first barrier); a user's first-stage option wins (the
    cold stage's solver then serves, nothing built); the cold smooth before
    it keeps fatrop's defaults."""
    from belief_nlp.methods import fatrop
    from belief_nlp.methods.nlp_build import clear_cache

    built = []
    plain = type(fatrop.FATROP).nlpsol

    def nlpsol(self, name, nlp, options):
        built.append(options["fatrop"].get("mu_init"))
        return plain(self, name, nlp, options)
    monkeypatch.setattr(type(fatrop.FATROP), "nlpsol", nlpsol)
    sc, path = hand10
    for user, expected in (({}, [fatrop.RESUME_FATROP_OPTIONS["mu_init"]]), ({"mu_init": 1e-2}, [])):
        clear_cache()
        built.clear()
        kw = {"method": "fatrop", "alpha": 1.0, "first_stage_options": user or None}
        previous = bn.smooth(sc, bn.warm_start(sc, path), **kw)
        assert built[0] == user.get("mu_init")                     # the cold first stage: fatrop's own default
        built.clear()
        moved = _moved(sc, previous.path, 1, np.random.default_rng(2))
        r = bn.replan(moved, previous, advance=1, **kw)
        assert r.stats["resumed"] == "graph" and built[:1] == expected
