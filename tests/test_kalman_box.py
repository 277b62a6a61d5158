"""The Kalman box of the lifted prior-information factors (NLPProblem.kalman_box)
and the restart inside it (docs/numerics.md, "The Kalman box")."""

from __future__ import annotations

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.model import BeliefModel
from belief_nlp.model.data import Layout
from belief_nlp.model.nlp_form import build_nlp


def _kalman_point(model: BeliefModel, S: np.ndarray, rng: np.random.Generator) -> Layout:
    """A point whose priors follow the Kalman recursion from sensing ``S``,
    rolled out here in numpy (not by the model)."""
    D = model.data
    K, d = D.K, D.d
    Q = np.zeros((K + 1, d, d))
    Q[1] = np.linalg.inv(D.P0 + D.W)
    for k in range(2, K + 1):
        Q[k] = np.linalg.inv(np.linalg.inv(Q[k - 1] + S[k - 1]) + D.W)
        Q[k] = 0.5 * (Q[k] + Q[k].T)
    x = np.vstack([D.x0, D.x0 + rng.normal(size=(K, d))])
    return Layout(x, Q, S, np.zeros((K, D.J, D.F)))


@pytest.mark.parametrize("name", ["tutorial", "paper-multi", "cube3d"])
def test_the_box_holds_every_kalman_point_and_is_tight(name):
    sc = bn.load_scenario(name)
    model = BeliefModel(sc, 8, 1.0)
    nlp = build_nlp(model, "cholesky")
    d = model.data.d
    t = d * (d + 1) // 2
    lb, ub = nlp.kalman_box(nlp.lbz, nlp.ubz)
    m = slice(nlp.info["m_offset"], nlp.info["m_offset"] + t * 7)
    assert np.all(np.isfinite(ub[m])) and np.all(ub[m] > 0)
    assert np.array_equal(np.delete(lb, np.r_[m]), np.delete(nlp.lbz, np.r_[m]))      # only M is boxed
    assert np.array_equal(np.delete(ub, np.r_[m]), np.delete(nlp.ubz, np.r_[m]))
    rng = np.random.default_rng(0)
    top = np.zeros(t * 7)
    for scale in (0.0, 1e-3, 1.0, 1e3, 1e8):        # none, weak ... overwhelming sensing
        for _ in range(5):
            G = rng.normal(size=(9, d, d))
            S = scale * G @ np.swapaxes(G, 1, 2)
            S[0] = 0.0
            z = nlp.pack(_kalman_point(model, S, rng))
            assert np.all(lb[m] < z[m]) and np.all(z[m] < ub[m]), (name, scale)
            top = np.maximum(top, np.abs(z[m]) / ub[m])
    # overwhelming sensing drives Q_k to W^-1: the diagonal of M reaches its bound
    diag = np.tile([i == j for i, j in nlp.info["tri"]], 7)
    assert top[diag].min() > 0.99


def test_an_nlp_without_lifted_priors_is_not_boxed():
    model = BeliefModel(bn.load_scenario("tutorial"), 6, 1.0)
    nlp = build_nlp(model, "eliminated")
    lb, ub = nlp.kalman_box(nlp.lbz, nlp.ubz)
    assert np.array_equal(lb, nlp.lbz) and np.array_equal(ub, nlp.ubz)


@pytest.mark.parametrize("seed,K", [(0, 8), (0, 12), (2, 10)])
def test_ipopt_converges_on_the_tutorial_at_high_confidence(seed, K):
    # chi2 = 10.4 (99.45 %): from these starts IPOPT's first attempt ran into
    # Infeasible_Problem_Detected with no safe point below its start (session 19:
    # 12 of 52 tutorial cases at chi2 10.4 / 13.8); the restart inside the box converges
    sc = bn.load_scenario("tutorial").with_options(chi2_value=10.4)
    plan = bn.plan(sc, seed=seed, alpha=1.0)
    res = bn.smooth(sc, plan, method="ipopt", K=K, alpha=1.0)
    assert res.status == "converged"
    assert bn.verify(sc, res.path).safe
    assert res.cost <= res.initial_cost
    ccp = bn.smooth(sc, plan, method="ccp", K=K, alpha=1.0)      # a second solver from the same start
    assert ccp.status == "converged"
    assert res.cost <= ccp.cost * 1.005


def test_the_recorder_stops_an_iterate_far_outside_the_box():
    from belief_nlp.methods.nlp_recorder import RUNAWAY, Recorder
    from belief_nlp.model.nlp_prefix import frozen

    sc = bn.load_scenario("tutorial")
    nlp = build_nlp(BeliefModel(sc, 8, 1.0), "logchol")
    lay = bn.warm_start(sc, bn.plan(sc, seed=0).path, K=8)
    z = nlp.pack(BeliefModel(sc, 8, 1.0).from_path(lay.path, lay.lam))
    _, ub = nlp.kalman_box(nlp.lbz, nlp.ubz)
    m = nlp.info["m_offset"] + 4                     # an entry of M_3
    rec = Recorder(nlp, keep=1, bar=None)

    def stops(value: float, runaway: bool) -> bool:
        rec.reset(keep=1, bar=None, stall=0, runaway=runaway)
        rec.begin(nlp.anchor(nlp.unpack(z)), budget=100, deadline=None)
        zv = z.copy()
        zv[m] = value
        f, g = nlp.fg(zv, rec.pv)
        rec._take(z, 0.0, np.asarray(nlp.fg(z, rec.pv)[1]).ravel())      # iteration 0 (the start) is not read
        return rec._take(zv, float(f), np.asarray(g).ravel())

    assert stops(-1.01 * RUNAWAY * ub[m], True) and rec.stop_reason == "left_box"
    assert not stops(0.99 * RUNAWAY * ub[m], True) and rec.stop_reason == ""
    assert not stops(1.01 * RUNAWAY * ub[m], False)
    # a frozen prefix's factors hold the start belief's information, not a Kalman
    # step's: they are not watched
    short = BeliefModel(sc, 6, 1.0)
    view = frozen(nlp, short, 2)
    rec.bind(view)
    fixed = np.flatnonzero(view.lbz == view.ubz)
    assert rec._m.size and not np.intersect1d(rec._m, fixed).size


def test_the_recorder_stops_an_attempt_that_walks_infeasible():
    """WALK consecutive iterates infeasible by more than WALK_VIOLATION end
    the attempt ("walked", restarted inside the box by the engine); one
    feasible enough iterate in between starts the count again; without
    ``runaway`` nothing stops."""
    from belief_nlp.methods.nlp_recorder import WALK, WALK_VIOLATION, Recorder

    sc = bn.load_scenario("tutorial")
    nlp = build_nlp(BeliefModel(sc, 8, 1.0), "logchol")
    lay = bn.warm_start(sc, bn.plan(sc, seed=0).path, K=8)
    z = nlp.pack(BeliefModel(sc, 8, 1.0).from_path(lay.path, lay.lam))
    rec = Recorder(nlp, keep=1, bar=None)
    f, g = nlp.fg(z, nlp.anchor(nlp.unpack(z)))
    g = np.asarray(g).ravel()
    far = g.copy()
    far[0] = nlp.lbg[0] - 2 * WALK_VIOLATION                  # a collision row violated by 20

    def run(rows: list, runaway: bool = True) -> int:
        """Feed ``rows`` (after the start); the 1-based row that stopped, or 0."""
        rec.reset(keep=1, bar=None, stall=0, runaway=runaway)
        rec.begin(nlp.anchor(nlp.unpack(z)), budget=10_000, deadline=None)
        rec._take(z, float(f), g)
        for i, gv in enumerate(rows, 1):
            if rec._take(z, float(f), gv):
                return i
        return 0

    assert run([far] * WALK) == WALK and rec.stop_reason == "walked"
    assert run([far] * (WALK - 1) + [g] + [far] * (WALK - 1)) == 0 and rec.stop_reason == ""
    assert run([far] * (2 * WALK), runaway=False) == 0
