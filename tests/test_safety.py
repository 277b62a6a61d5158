"""The safety contract (docs/safety.md): answers carry Theorem-1 certificates,
verify checks them in closed form, and acceptance rests on that lower bound."""

from __future__ import annotations

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.errors import ValidationError
from belief_nlp.smoother.policy import DEFAULT_POLICY, SafetyPolicy

from conftest import paper_multi_path_pair


@pytest.fixture(scope="module")
def run():
    sc, path = paper_multi_path_pair(steps_per_segment=2)
    return sc, bn.smooth(sc, path, alpha=1.0, max_iter=30)


@pytest.mark.parametrize("method", ["ccp", "ipopt"])
def test_answers_carry_certificates_that_prove_every_pair(method):
    sc, path = paper_multi_path_pair(steps_per_segment=2)
    res = bn.smooth(sc, path, method=method, alpha=1.0)
    assert res.certificates.shape == (res.path.K, len(sc.hazards), max(h.n_faces for h in sc.hazards))
    rep = bn.verify(sc, res.path, certificates=res.certificates)
    assert rep.safe and rep.proof == "certificates+sampling"
    assert res.verification["proof"] == "certificates+sampling"
    # the certificate margins are lower bounds of the sampled ones
    assert np.all(rep.certificate_margins <= rep.transition_margins + 1e-9)
    # and verify reads them from the result itself
    assert bn.verify(sc, res).proof == "certificates+sampling"


def test_certificates_that_prove_nothing_make_the_path_unproven(run):
    sc, res = run
    lam = res.certificates
    for bad, word in ((-lam, "lam >= 0"), (1e-6 * lam, "does not prove"), (np.full_like(lam, np.nan), ">= 0")):
        rep = bn.verify(sc, res.path, certificates=bad)
        assert not rep.safe and rep.proof == "sampling"
        assert any(word in p for p in rep.problems), rep.problems
    # without certificates the sampled second opinion alone decides
    assert bn.verify(sc, res.path, certificates=None).proof == "sampling"
    with pytest.raises(ValidationError) as exc:
        bn.verify(sc, res.path, certificates=lam[:, :2])
    assert exc.value.field == "certificates"


def test_result_certificates_round_trip(run, tmp_path):
    sc, res = run
    back = bn.SmoothResult.load(res.save(tmp_path / "r.json"))
    np.testing.assert_array_equal(back.certificates, res.certificates)
    assert back == res


def test_check_lower_bound_never_exceeds_the_exact_minimum(run):
    """Check.margin (certificates, closed form) <= Check.upper (exact 1-D
    minimisation) at perturbed points, and acceptance follows the policy."""
    from belief_nlp.smoother.context import SmoothingProblem

    sc, res = run
    ws = bn.warm_start(sc, res.path)
    model = bn.smoother.driver.BeliefModel(sc, ws.K, 1.0)
    prob = SmoothingProblem(sc, ws, model, max_iter=1, tol=1e-4, time_limit=None, t0=0.0, solver=None,
                            solver_options={}, progress=False, keep_iterates=False, callback=None, method="x")
    rng = np.random.default_rng(0)
    for _ in range(10):
        z = prob.start.copy()
        z.x[1:-1] += 1e-3 / model.data.sigma * rng.normal(size=z.x[1:-1].shape)
        z.S[1:] *= np.exp(rng.normal())
        chk = prob.check(model.tighten(z))
        assert chk.margin <= chk.upper + 1e-9 * (1 + abs(chk.upper))
        assert chk.safe == (chk.margin >= DEFAULT_POLICY.accept * model.data.chi2 and chk.target >= 0)


def test_policy_orders_its_margins():
    with pytest.raises(ValueError):
        SafetyPolicy(conic=1e-8, accept=1e-7)
    p = DEFAULT_POLICY
    assert p.warm_start >= p.conic > p.accept >= 0 and p.nlp > p.accept


def test_summary_names_the_cost_and_the_proof(run, capfd):
    sc, res = run
    text = res.summary()
    assert "steering cost at K = 10" in text and "certificates+sampling" in text and res.method in text
    r = bn.smooth(sc, res.path, method="ccp", max_iter=2, verbose=True)
    assert "CCP iteration 1" in capfd.readouterr().err and r.nit == 2
