"""Re-plans after executed steps (receding horizon) on the longer graph with
its first steps frozen (belief_nlp.model.nlp_prefix).

The frozen NLP must be the shorter problem term by term: checked against
the shorter problem's own NLP at perturbed points (rows, cost parts,
margins), and end to end against re-plans that build the shorter horizon
and start from the path alone.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.allocation import RiskBudget
from belief_nlp.model import BeliefModel
from belief_nlp.model.nlp_form import build_nlp
from belief_nlp.model.nlp_prefix import frozen

from conftest import assert_frozen_is_shorter, paper_multi_path_pair

KW = {"method": "ipopt", "alpha": 1.0, "max_iter": 3000}


@pytest.fixture(scope="module")
def plan10():
    """paper-multi on the hand route (K = 10) and IPOPT's answer."""
    sc, path = paper_multi_path_pair(2)
    return sc, bn.smooth(sc, bn.warm_start(sc, path), **KW)


def _moved(sc, previous, step: int, rng) -> bn.Scenario:
    """The robot after ``step`` executed steps: near the plan's belief there,
    with a smaller covariance (a measurement went well) and the mean moved
    up to 0.5 mm."""
    return sc.with_options(x0=previous.path.x[step] + 5e-4 * rng.uniform(-1, 1, 2), P0=0.7 * previous.path.P[step])


@pytest.mark.parametrize("formulation, offset, relaxed", [("cholesky", 1, False), ("logchol", 1, False),
                                                           ("logchol", 3, False), ("cholesky", 2, True)])
def test_the_frozen_nlp_is_the_shorter_problem(plan10, formulation, offset, relaxed):
    """At perturbed points of the shorter problem, the frozen K-step NLP has
    its margins, cost parts and rows against their bounds (the extra Kalman
    block holds the shorter problem's fixed Q_1: 0 at Kalman-consistent
    points), and its objective differs by one constant (the frozen steps'
    information). Also with the start held to its own level (``relaxed``:
    the shorter NLP adds the relief to its transition 1's rows, the frozen
    one takes it off their bounds)."""
    sc, previous = plan10
    K = previous.path.K
    moved = _moved(sc, previous, offset, np.random.default_rng(offset))
    if relaxed:
        moved = moved.with_options(start_confidence=0.7)
    long_model, short_model = BeliefModel(sc, K, 1.0), BeliefModel(moved, K - offset, 1.0)
    view = frozen(build_nlp(long_model, formulation, floor=1e-3), short_model, offset)
    short = build_nlp(short_model, formulation, floor=1e-3)
    ws = bn.warm_start(moved, bn.reanchor(moved, previous, advance=offset), sensing="path")
    z0 = short_model.tighten(short_model.from_path(ws.path, ws.lam))
    for q, zv, gv, gs in assert_frozen_is_shorter(view, short, short_model, z0, np.random.default_rng(7)):
        n_rows = short.n_collision + short.info["n_target"]
        t = len(short.info["tri"])
        np.testing.assert_allclose(gv[n_rows:n_rows + t], 0.0, atol=1e-9)       # Q_{offset+1} = (P0 + W)^-1
        np.testing.assert_allclose(gv[n_rows + t:], gs[n_rows:], rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(view.unpack(zv).S[1:], q.S[1:], rtol=1e-9, atol=1e-9)
    # the frozen variables are the prefix's; the free ones the shorter problem's and M_{offset+1}
    free = view.lbz < view.ubz
    assert free.sum() == (short.lbz < short.ubz).sum() + len(short.info["tri"])


def test_a_prefix_that_cannot_be_frozen_is_refused(plan10):
    """A floored ("logchol") prefix needs P0^-1 > floor^2 I; a risk budget's
    levels depend on the horizon."""
    sc, previous = plan10
    K = previous.path.K
    nlp = build_nlp(BeliefModel(sc, K, 1.0), "logchol", floor=10.0)      # scaled units: P0 = W is 1
    wide = sc.with_options(P0=sc.W)
    with pytest.raises(bn.ValidationError) as err:
        frozen(nlp, BeliefModel(wide, K - 1, 1.0), 1)
    assert err.value.field == "resume"
    with pytest.raises(bn.ValidationError):
        frozen(nlp, BeliefModel(sc, K - 2, 1.0), 1)           # horizons that do not add up
    with pytest.raises(bn.ValidationError):
        frozen(nlp, BeliefModel(sc, K - 1, 1.0, risk=RiskBudget(0.05)), 1)


def test_a_receding_loop_reuses_the_graph_and_answers_as_a_fresh_horizon(plan10):
    """Three executed steps, one at a time: each re-plan resumes on the
    K = 10 graph (nothing built), answers as the re-plan that builds the
    shorter horizon from the re-anchored path (cost to 1e-5, the polish's
    tolerance: both are the same local optimum to it), in fewer
    iterations, verified and no costlier than its warm start."""
    sc, previous = plan10
    rng = np.random.default_rng(0)
    K = previous.path.K
    for step in range(1, 4):
        moved = _moved(sc, previous, 1, rng)
        r = bn.replan(moved, previous, advance=1, **KW)
        ref = bn.replan(moved, dataclasses.replace(previous, resume=None), advance=1, **KW)
        assert r.stats["resumed"] == "yes" and ref.stats["resumed"] == "no"
        assert r.stats["build"] in ("memory", "built (derivatives shared)")
        assert r.status == "converged" and r.safe and bn.verify(moved, r.path).safe
        assert r.path.K == K - step and r.cost <= r.initial_cost
        np.testing.assert_allclose(r.path.x[0], moved.x0, rtol=1e-15, atol=0)
        assert r.cost == pytest.approx(ref.cost, rel=1e-5)
        assert r.nit < ref.nit
        assert r.resume["offset"] == step            # the next re-plan freezes one more step
        previous = r


def test_two_steps_at_once(plan10):
    """advance = 2 freezes two steps at once."""
    sc, previous = plan10
    moved = _moved(sc, previous, 2, np.random.default_rng(1))
    r = bn.replan(moved, previous, advance=2, **KW)
    assert r.stats["resumed"] == "yes" and r.status == "converged" and bn.verify(moved, r.path).safe
    assert r.cost == pytest.approx(bn.replan(moved, dataclasses.replace(previous, resume=None), advance=2,
                                             **KW).cost, rel=1e-6)


def test_when_the_frozen_solve_fails_the_usual_stage_runs_on_the_same_graph(plan10, resume_fails):
    """The usual first stage from the warm start follows on the frozen graph
    (nothing built) and answers as the re-plan that builds the shorter
    horizon; when the prefix cannot be frozen, the shorter horizon is built."""
    sc, previous = plan10
    moved = _moved(sc, previous, 2, np.random.default_rng(1))
    ref = bn.replan(moved, dataclasses.replace(previous, resume=None), advance=2, **KW)
    back = bn.replan(moved, previous, advance=2, **KW)
    assert back.stats["resumed"] == "fell back" and back.status == "converged" and back.safe
    assert back.stats["build"] in ("memory", "built (derivatives shared)")
    assert back.resume["offset"] == 2                # the state of the graph that answered
    assert back.cost == pytest.approx(ref.cost, rel=1e-6)
    assert bn.verify(moved, back.path).safe


def test_the_last_polish_resumes_alone(plan10):
    """When the last answer is its polish's, the re-plan resumes that stage
    alone (its variables and multipliers, its switched-off sensing kept
    off): the first stage does not run; fewer iterations than resuming the
    first stage and polishing, the same answer to the polish's tolerance,
    and the steps that sensed nothing still sense nothing."""
    sc, previous = plan10
    assert previous.resume["polish"] is not None and "polished" in previous.message
    moved = _moved(sc, previous, 1, np.random.default_rng(5))
    r = bn.replan(moved, previous, advance=1, **KW)
    both = bn.replan(moved, dataclasses.replace(previous, resume={**previous.resume, "polish": None}), advance=1,
                     **KW)
    assert r.stats["resumed"] == "yes" and r.stats["resumed_stage"] == "polish"
    assert [a["formulation"] for a in r.stats["attempts"]] == ["cholesky"]
    assert both.stats["resumed_stage"] == "first" and len(both.stats["attempts"]) == 2
    assert r.status == "converged" and bn.verify(moved, r.path).safe and r.cost <= r.initial_cost
    assert r.cost == pytest.approx(both.cost, rel=1e-5) and r.nit < both.nit
    off = [k for k in range(1, previous.path.K) if not previous.path.S[k].any()]
    assert off and all(not r.path.S[k - 1].any() for k in off)
    # the next re-plan goes on from this polish; the first stage's state is the earlier one's
    assert r.resume["offset"] == 1 and r.resume["polish"] is not None
    np.testing.assert_array_equal(r.resume["z"], previous.resume["z"])


def test_when_the_resumed_polish_fails_the_first_stage_resumes(plan10, polish_resume_fails):
    """The failed polish attempt is counted; the resumed first stage and its
    polish then answer as a fresh horizon does; a run whose answer is not its
    polish's keeps no polish state."""
    sc, previous = plan10
    moved = _moved(sc, previous, 1, np.random.default_rng(5))
    r = bn.replan(moved, previous, advance=1, **KW)
    ref = bn.replan(moved, dataclasses.replace(previous, resume=None), advance=1, **KW)
    assert r.stats["resumed"] == "yes" and r.stats["resumed_stage"] == "first"
    assert [a["formulation"] for a in r.stats["attempts"]] == ["cholesky", "logchol", "cholesky"]
    assert r.nit == sum(a["iter_count"] for a in r.stats["attempts"])
    assert r.status == "converged" and bn.verify(moved, r.path).safe
    assert r.cost == pytest.approx(ref.cost, rel=1e-5)
    unpolished = bn.smooth(sc, previous.path, method="ipopt", alpha=1.0, max_iter=3000, polish=0)
    assert unpolished.resume is not None and unpolished.resume["polish"] is None
    bad = {**previous.resume, "polish": {"z": previous.resume["z"]}}
    with pytest.raises(bn.ValidationError) as err:
        bn.replan(moved, previous, advance=1, resume=bad, **KW)
    assert err.value.field == "resume"


def test_a_prefix_that_cannot_be_frozen_builds_the_shorter_horizon(plan10):
    """A floored prefix needs P0^-1 > floor^2 I: with a floor that the start
    covariance exceeds, the resume state does not fit and the re-plan builds
    its horizon (and answers)."""
    sc, previous = plan10
    moved = _moved(sc, previous, 1, np.random.default_rng(4))
    state = bn.smooth(sc, previous.path, method="ipopt", alpha=1.0, max_iter=3000, floor=30.0)
    r = bn.replan(moved, state, advance=1, method="ipopt", alpha=1.0, max_iter=3000, floor=30.0)
    assert r.stats["resumed"] == "does not fit" and (r.resume is None or r.resume["offset"] == 0)
    # (such a floor is far from the answer's sensing: the status is the floor's business, the answer safe)
    assert r.safe and bn.verify(moved, r.path).safe and r.cost <= r.initial_cost


def test_under_a_risk_budget_a_receding_replan_builds_its_horizon(plan10):
    """A risk budget's levels depend on the number of pairs: the longer
    graph does not fit, the re-plan builds its own (and answers)."""
    sc, _ = plan10
    risk = RiskBudget(0.05, allocation="uniform")
    path = paper_multi_path_pair(2)[1]
    previous = bn.smooth(sc, path, risk=risk, **KW)
    assert previous.resume is not None
    moved = _moved(sc, previous, 1, np.random.default_rng(2))
    r = bn.replan(moved, previous, advance=1, risk=risk, **KW)
    assert r.stats["resumed"] == "does not fit" and r.status == "converged"
    assert bn.verify(moved, r.path).safe and r.risk is not None


@pytest.mark.parametrize("offset, relaxed", [(1, False), (3, False), (2, True)])
def test_the_frozen_conic_step_answers_as_the_shorter_horizons_own(plan10, offset, relaxed):
    """The longer CCP step with its prefix frozen, at a point of the shorter
    problem, is a step of the shorter problem: its answer (every pair kept,
    and the active-set step's pairs) is proven clear by its certificates,
    lowers the cost, and lands where the shorter horizon's own step lands
    (means to 1e-5, cost to 1e-5 relative). Not bit for bit: the longer step
    holds transition 1's start end in the generic majorised form (its split
    term also weighs the certificates' change), the shorter one exactly
    (C8); both are majorants tight at the point, so CCP's fixed points are
    the same (the polish test below). Also with the start held to its own
    level (``relaxed``: the relief is the step's parameter at the
    transition after the prefix)."""
    from belief_nlp.geometry import PolytopeSet
    from belief_nlp.methods.ccp import active_pairs, initial_rho
    from belief_nlp.model.conic_form import conic_step
    from belief_nlp.model.conic_prefix import frozen_conic

    sc, previous = plan10
    K = previous.path.K
    moved = _moved(sc, previous, offset, np.random.default_rng(10 + offset))
    if relaxed:
        moved = moved.with_options(start_confidence=0.7)
    long_model, short_model = BeliefModel(sc, K, 1.0), BeliefModel(moved, K - offset, 1.0)
    view = frozen_conic(conic_step(long_model.convex_form), short_model.data, offset)
    own = conic_step(short_model.convex_form)
    ws = bn.warm_start(moved, bn.reanchor(moved, previous, advance=offset), sensing="path")
    q = short_model.tighten(short_model.from_path(ws.path, ws.lam))
    rho = initial_rho(short_model, q)
    hazards = PolytopeSet.cached([(h.A, h.b / short_model.data.sigma) for h in moved.hazards])
    keeps = [np.ones(short_model.data.K * short_model.data.J, bool), active_pairs(short_model, q, hazards)]
    assert not keeps[1].all()
    for keep in keeps:
        st_v, z_v, _, _ = view.solve(q, rho, rho, keep)
        st_o, z_o, _, _ = own.solve(q, rho, rho, keep)
        assert st_v == st_o == "optimal"
        a, b = view.layout.extract(z_v, q), own.layout.extract(z_o, q)
        ca_, cb = short_model.cost(short_model.tighten(a))[0], short_model.cost(short_model.tighten(b))[0]
        # two different (equivalent) conic forms solved to Clarabel's tolerances: their means
        # agree to the solver's accuracy, not to the bit (1.5e-5 relative on one mean on an AMD
        # EPYC host, session 19); 1e-3 scaled units is a thousandth of one step's noise. A relaxed
        # start's first transition rides its level, where the majorants differ most: one step's
        # means 0.02 apart and its cost 2e-5 (the fixed points agree: test_receding_ccp)
        np.testing.assert_allclose(a.x, b.x, rtol=0, atol=0.05 if relaxed else 1e-3)   # scaled: x ~ 10-50
        assert ca_ == pytest.approx(cb, rel=1e-4 if relaxed else 1e-5)
        start, end = short_model.transition_margins(short_model.tighten(a))
        assert min(start.min(), end.min()) >= -1e-6 * short_model.data.chi2
        assert ca_ < short_model.cost(q)[0]               # a step that lowers the cost, not the point itself


def test_autos_ccp_polish_in_a_receding_replan_uses_the_frozen_step(plan10):
    """auto's CCP polish after a frozen IPOPT stage uses the longer horizon's
    conic step (nothing built for the shorter one) and answers as the
    polish on the shorter horizon's own step (cost to 1e-6)."""
    from belief_nlp.model.cache import MEMORY

    sc, previous = plan10
    # polished (its conic step built), whether or not the answer is stationary in S
    first = bn.smooth(sc, previous.path, method="auto", alpha=1.0, ccp_polish=10)
    moved = _moved(sc, first, 1, np.random.default_rng(3))
    r = bn.replan(moved, first, advance=1, alpha=1.0, ccp_polish=10)     # (the default skips it here: below)
    assert r.stats["ipopt"]["resumed"] == "yes" and r.stats["ccp"]["frozen"] == 1
    # the frozen step answered (its answers were taken, not left to IPOPT's point)
    assert r.stats["ccp"]["steps"] and all((s["solver"] or "").startswith("CLARABEL") for s in r.stats["ccp"]["steps"])
    assert r.status == "converged" and bn.verify(moved, r.path).safe
    MEMORY.clear()                                     # the longer step gone: the polish builds its own
    own = bn.replan(moved, first, advance=1, alpha=1.0, ccp_polish=10)
    assert own.stats["ccp"]["frozen"] == 0
    assert r.cost == pytest.approx(own.cost, rel=1e-6)


def test_a_polish_that_did_not_lower_the_answer_is_skipped_by_the_next_replans(plan10, monkeypatch):
    """A run whose polish could not lower its answer (here: every sensing
    column switched off, which no safe point allows) tells the next
    POLISH_RETRY re-plans to skip it; they answer from the first stage,
    verified, and count the skips down."""
    from belief_nlp.methods.nlp_engine import POLISH_RETRY
    from belief_nlp.model.nlp_form import NLPProblem

    sc, previous = plan10
    with monkeypatch.context() as mp:
        mp.setattr(NLPProblem, "without_sensing",
                   lambda self, lay, floor, slack=0.1: self.switch_off(self.pack(lay), self.lbz, self.ubz, 1e9))
        failed = bn.smooth(sc, previous.path, step_down=0, **KW)    # (a lower floor's best point is lower)
    assert "not lower; not used" in failed.message and failed.resume["polish_skip"] == POLISH_RETRY
    assert failed.resume["polish"] is None
    moved = _moved(sc, failed, 1, np.random.default_rng(8))
    r = bn.replan(moved, failed, advance=1, **KW)
    assert r.stats["polish_skipped"] and [a["formulation"] for a in r.stats["attempts"]] == ["logchol"]
    assert r.resume["polish_skip"] == POLISH_RETRY - 1 and "polish skipped" in r.message
    assert r.status == "converged" and bn.verify(moved, r.path).safe
    last = bn.replan(moved, dataclasses.replace(r, resume={**r.resume, "polish_skip": 0}), advance=0, **KW)
    assert not last.stats["polish_skipped"] and last.resume["polish_skip"] == 0      # polished again
    kept = bn.replan(moved, failed, advance=1, polish_retry=0, **KW)                 # (auto's IPOPT stage)
    assert not kept.stats["polish_skipped"] and kept.stats["attempts"][-1]["formulation"] == "cholesky"


def test_autos_default_skips_the_ccp_polish_after_a_resumed_polish(plan10):
    """By default auto's CCP polish does not run after an IPOPT stage that
    resumed and ended on its converged exact polish (a loop's re-plan: the
    polish changed the cost by at most 1.4e-5 there); the answer is IPOPT's,
    verified, within 1e-4 of the polished one."""
    sc, previous = plan10
    first = bn.smooth(sc, previous.path, method="auto", alpha=1.0, ccp_polish=10)
    assert first.stats["stages"] == ["ipopt", "ccp polish"]
    moved = _moved(sc, first, 1, np.random.default_rng(3))
    r = bn.replan(moved, first, advance=1, alpha=1.0)
    assert r.stats["ipopt"]["resumed"] == "yes" and r.stats["ipopt"]["resumed_stage"] == "polish"
    assert r.stats["stages"] == ["ipopt"] and r.method == "auto:ipopt" and "ccp" not in r.stats
    assert r.status == "converged" and bn.verify(moved, r.path).safe
    polished = bn.replan(moved, first, advance=1, alpha=1.0, ccp_polish=10)
    assert polished.stats["stages"] == ["ipopt", "ccp polish"]
    assert polished.cost <= r.cost <= polished.cost * (1 + 1e-4)


def test_autos_ccp_answer_keeps_ipopts_state_and_the_frozen_step(plan10, monkeypatch):
    """When IPOPT's converged answer is not taken (here made costlier than
    the warm start), auto answers by CCP on the longer horizon's conic step,
    frozen alike, and keeps IPOPT's state: the next ``ipopt_retry`` re-plans
    run CCP alone on that step (the answer of ``method="ccp"`` from the same
    state), and then IPOPT resumes on the same graph instead of building
    its horizon."""
    from belief_nlp.methods import auto

    sc, previous = plan10
    first = bn.smooth(sc, previous.path, method="auto", alpha=1.0)
    real = auto.FIRST_STAGE.run

    def above_start(problem, **kw):
        out = real(problem, **kw)
        if out.point is not None:             # the answer with 4x the sensing: safe, and costlier than the start
            out.point = problem.model.tighten(dataclasses.replace(problem.start, S=4 * problem.start.S))
        return out

    monkeypatch.setattr(auto.FIRST_STAGE, "run", above_start)
    moved = _moved(sc, first, 1, np.random.default_rng(6))
    r = bn.replan(moved, first, advance=1, alpha=1.0)
    assert r.method == "auto:ccp" and r.stats["ipopt"]["resumed"] == "yes" and r.stats["ccp"]["frozen"] == 1
    assert r.status == "converged" and bn.verify(moved, r.path).safe and r.cost <= r.initial_cost
    assert r.resume is not None and r.resume["offset"] == 1 and r.resume["stage_skip"] == auto.IPOPT_RETRY
    assert bn.replan(moved, first, advance=1, alpha=1.0, ipopt_retry=0).resume["stage_skip"] == 0
    with pytest.raises(bn.ValidationError) as err:
        bn.replan(moved, first, advance=1, alpha=1.0, ipopt_retry=-1)
    assert err.value.field == "ipopt_retry"
    monkeypatch.setattr(auto.FIRST_STAGE, "run", real)
    moved2 = _moved(sc, r, 1, np.random.default_rng(7))
    nxt = bn.replan(moved2, r, advance=1, alpha=1.0)
    assert nxt.method == "auto:ccp" and nxt.stats["ipopt_skipped"] and "ipopt" not in nxt.stats
    assert nxt.stats["ccp"]["frozen"] == 2 and nxt.resume["offset"] == 2
    assert nxt.resume["stage_skip"] == auto.IPOPT_RETRY - 1 and nxt.status == "converged"
    alone = bn.replan(moved2, r, advance=1, alpha=1.0, method="ccp")
    assert alone.cost == pytest.approx(nxt.cost, rel=1e-12) and bn.verify(moved2, nxt.path).safe
    # with the skips spent (or ipopt_retry=0) IPOPT resumes on the same graph
    spent = dataclasses.replace(r, resume={**r.resume, "stage_skip": 0})
    back = bn.replan(moved2, spent, advance=1, alpha=1.0)
    assert back.stats["ipopt"]["resumed"] == "yes" and back.resume["offset"] == 2
    assert back.resume["stage_skip"] == 0 or back.method == "auto:ccp"


@pytest.mark.parametrize("offset", [-1, 1.0, True, "1"])
def test_a_resume_state_with_a_bad_offset_is_our_error(plan10, offset):
    sc, previous = plan10
    with pytest.raises(bn.ValidationError) as err:
        bn.smooth(sc, previous.path, resume={**previous.resume, "offset": offset}, **KW)
    assert err.value.field == "resume"


def test_a_receding_replan_in_three_dimensions():
    """The frozen forms are dimension-generic: on cube3d (d = 3) a re-plan
    after one executed step resumes on the longer graph and answers as the
    re-plan that builds its horizon; auto's polish runs on the frozen conic
    step."""
    sc = bn.load_scenario("cube3d")
    plan = bn.plan(sc, n_nodes=300, seed=0, noise="per_step")
    previous = bn.smooth(sc, plan.path, K=10, **KW)
    now = sc.with_options(x0=previous.path.x[1] + 2e-4, P0=0.8 * previous.path.P[1])
    r = bn.replan(now, previous, advance=1, **KW)
    ref = bn.replan(now, dataclasses.replace(previous, resume=None), advance=1, **KW)
    assert r.stats["resumed"] == "yes" and r.nit < ref.nit
    assert r.cost == pytest.approx(ref.cost, rel=1e-6) and bn.verify(now, r.path).safe
    auto = bn.replan(now, bn.smooth(sc, plan.path, K=10, alpha=1.0, ccp_polish=10), advance=1, alpha=1.0,
                     ccp_polish=10)
    assert auto.stats["ipopt"]["resumed"] == "yes" and auto.stats["ccp"]["frozen"] == 1
    assert bn.verify(now, auto.path).safe and auto.cost <= auto.initial_cost


@pytest.mark.skipif("sqp" not in bn.available_methods(), reason="the sqp method needs unopy")
def test_a_replan_from_the_planned_belief_is_converged_at_its_start():
    """No disturbance: the re-plan's warm start (the last answer's tail) is
    already optimal, and IPOPT converges 1e-6 above it. That was
    "above_start", a failure, in every such loop step; the start is optimal
    to tol, so it is returned as converged."""
    sc = bn.load_scenario("tutorial").with_options(alpha=1.0)
    first = bn.smooth(sc, bn.plan(sc, n_nodes=400, seed=0, noise="per_step"), method="sqp")
    planned = sc.with_options(x0=first.path.x[1], P0=first.path.P[1])
    r = bn.replan(planned, first, advance=1, method="ipopt")
    assert r.status == "converged" and r.success and "the warm start is returned" in r.message
    assert r.cost == r.initial_cost and bn.verify(planned, r.path).safe
