"""The NLP methods' ``first_stage_options``: solver options of the first
("logchol") stage only, over the run's ``solver_options``."""

from __future__ import annotations

import pytest

import belief_nlp as bn
import belief_nlp.methods.nlp_engine as engine


def _stage_options(monkeypatch, sc, ws, **kw):
    """The result and the plug-in options each stage's solver was built with."""
    seen = []
    real = engine.solver_of

    def spy(model, backend, opts, formulation, *args, **kwargs):
        seen.append((formulation, dict(opts)))
        return real(model, backend, opts, formulation, *args, **kwargs)

    monkeypatch.setattr(engine, "solver_of", spy)
    return bn.smooth(sc, ws, **kw), seen


def test_they_reach_the_first_stage_only(monkeypatch, small_start):
    sc, ws = small_start
    plain, _ = _stage_options(monkeypatch, sc, ws, method="ipopt", alpha=1.0)
    res, seen = _stage_options(monkeypatch, sc, ws, method="ipopt", alpha=1.0,
                               solver_options={"mu_min": 1e-9, "acceptable_iter": 20},
                               first_stage_options={"ipopt.mu_min": 3e-6})
    stages = dict(seen)
    assert set(stages) == {"logchol", "cholesky"}
    assert stages["logchol"]["mu_min"] == 3e-6 and stages["logchol"]["acceptable_iter"] == 20
    assert stages["cholesky"]["mu_min"] == 1e-9                  # the polish keeps the run's
    assert res.status == "converged" and res.safe and bn.verify(sc, res.path).safe
    assert res.cost == pytest.approx(plain.cost, rel=1e-4)        # the same optimum, to the polish's tolerance


def test_auto_hands_them_to_its_ipopt_stage(monkeypatch, small_start):
    sc, ws = small_start
    res, seen = _stage_options(monkeypatch, sc, ws, method="auto", alpha=0.1,
                               ipopt_options={"first_stage_options": {"mu_min": 1e-7}})
    assert dict(seen)["logchol"]["mu_min"] == 1e-7                # not the default (3e-6)
    assert res.safe and res.method.startswith("auto")


def test_a_resumed_first_stage_keeps_its_floor_unless_the_user_sets_one(monkeypatch, small_start):
    """A first stage resumed from an earlier answer runs with the backend's
    resume options (barrier floor 1e-7, below its mu_init 1e-6), not the
    usual stage's 3e-6; the user's own first-stage floor wins over both."""
    sc, ws = small_start
    state = {**bn.smooth(sc, ws, method="ipopt", alpha=1.0).resume, "polish": None}     # the first stage's alone
    for given, floor in ((None, 1e-7), ({"mu_min": 2e-7}, 2e-7)):
        res, seen = _stage_options(monkeypatch, sc, ws, method="ipopt", alpha=1.0, resume=state,
                                   first_stage_options=given)
        assert res.stats["resumed_stage"] == "first" and res.safe
        assert [o["mu_min"] for f, o in seen if f == "logchol"] == [floor]


@pytest.mark.parametrize("value, words", [
    ([("mu_min", 1e-6)], "must be a dict"),
    ({"mu_min": [1e-6]}, "option 'mu_min' must be a number"),
    ({3: 1.0}, "must be a dict"),
])
def test_bad_values_are_refused_naming_the_field(small_start, value, words):
    sc, ws = small_start
    with pytest.raises(bn.ValidationError) as err:
        bn.smooth(sc, ws, method="ipopt", first_stage_options=value)
    assert err.value.field == "first_stage_options" and words in str(err.value)


def test_an_option_the_solver_refuses_is_named_as_a_first_stage_option(small_start):
    sc, ws = small_start
    with pytest.raises(bn.ValidationError) as err:
        bn.smooth(sc, ws, method="ipopt", first_stage_options={"mu_minimum": 1e-6})
    assert err.value.field == "first_stage_options" and "mu_minimum" in str(err.value)
    with pytest.raises(bn.ValidationError) as err:
        bn.smooth(sc, ws, method="ipopt", solver_options={"mu_minimum": 1e-6}, first_stage_options={"mu_min": 1e-6})
    assert err.value.field == "solver_options"
