"""The options every NLP method takes (the keywords of
:func:`belief_nlp.methods.nlp_engine.run_nlp`), with their checks."""

from __future__ import annotations

from ..model.nlp_form import FORMULATIONS
from ..smoother.policy import DEFAULT_POLICY
from ..smoother.registry import Option, count, nonneg, real
from . import nlp_resume
from .nlp_stepdown import STEP_DOWN

__all__ = ["nlp_options", "POLISH_RETRY", "REENTER", "STEP_DOWN"]

#: the default ``polish_retry``: re-plans (with ``resume``) that skip the
#: polish after a run whose polish did not lower its answer, while stage 1's
#: answer is below the warm start. At K = 80 the floor's sensing cannot be
#: switched off and the polish ran to its 50 iterations for nothing at every
#: re-plan (docs/numerics.md, "The polish resumed alone"); the fifth tries again
POLISH_RETRY = 4

#: the default ``reenter``: rounds of the polish that turn back on the
#: switched-off sensing whose block says it lowers the cost (nlp_reentry). On
#: the issue-21 protocol 2 of 40 answers at K = 40 took one round and became
#: stationary, 2 of 12 at K = 80 took three (docs/numerics.md, "Sensing back on
#: after the polish")
REENTER = 3


def _check_stage_options(v) -> str | None:
    """``first_stage_options``: None or a dict of option names to numbers, strings or bools."""
    if v is None:
        return None
    if not isinstance(v, dict) or not all(isinstance(k, str) for k in v):
        return "must be a dict of solver option names to values"
    bad = [k for k, x in v.items() if not (isinstance(x, (str, bool)) or real(x) is not None)]
    return f"option {bad[0]!r} must be a number, a string or a bool" if bad else None


def _check_step_down(v) -> str | None:
    """``step_down``: a factor in [0, 1) (0: no step-down)."""
    r = real(v)
    return None if r is not None and 0 <= r < 1 else "must be a number in [0, 1)"


def nlp_options(solver: str) -> dict[str, Option]:
    """The options every NLP method takes (the keywords of :func:`run_nlp`)."""
    return {
        "formulation": Option("logchol", f"NLP variables: one of {FORMULATIONS}",
                              lambda v: None if v in FORMULATIONS else f"must be one of {FORMULATIONS}"),
        "floor": Option(1e-2, "smallest diagonal entry of L in the 'logchol' stage (scaled units)",
                        lambda v: None if (real(v) or 0) > 0 else "must be a number > 0"),
        "polish": Option(50, "iteration cap of the polish after the 'logchol' stage (0: none)", count),
        "regularisation": Option(1e-4, "weight of the certificates' proximal term", nonneg),
        "margin": Option(DEFAULT_POLICY.nlp, "relative clearance margin kept in the NLP's collision rows", nonneg),
        "restarts": Option(1, "restarts after an unconverged stop: from the best safe point, or inside the "
                              "Kalman box (docs/numerics.md)", count),
        "stall": Option(300, "iterations without a lower feasible cost that end an attempt", count),
        "candidates": Option(5, "feasible iterates kept as fallback candidates", count),
        "cache": Option(True, f"reuse the NLP and {solver} instance of an earlier call with the same model",
                        lambda v: None if isinstance(v, bool) else "must be True or False"),
        "polish_retry": Option(POLISH_RETRY, "re-plans (with resume) that skip the polish after one whose polish "
                                             "did not lower its answer, while the first stage's answer is below "
                                             "the warm start (0: never skip)", count),
        "reenter": Option(REENTER, "rounds after the polish that turn back on the switched-off sensing whose "
                                   "Hessian block says it lowers the cost, one step a round (solvers that take "
                                   "initial multipliers: IPOPT; 0: none)", count),
        "step_down": Option(STEP_DOWN, "after a polish without an answer, or one whose switched-off sensing would "
                                       "still pay after the reenter rounds, the floored stage once more at floor x "
                                       "step_down from its answer and multipliers, then the polish at that floor "
                                       "(solvers that take initial multipliers: IPOPT; 0: none)",
                            _check_step_down),
        "first_stage_options": Option(None, f"{solver} options of the first stage only, over solver_options "
                                            "(e.g. IPOPT's {'mu_min': 1e-7}, its barrier floor before 3e-6: "
                                            "docs/numerics.md, \"The first stage's barrier floor\")",
                                      _check_stage_options),
        "resume": Option(None, "an earlier answer's first-stage state (SmoothResult.resume), on the same scenario "
                               "and K (bn.replan passes it): IPOPT starts that stage from its variables and "
                               "multipliers; fatrop and Uno, which take no multipliers, solve a re-plan after "
                               "executed steps on its graph, nothing built", nlp_resume.check),
    }
