"""Receding-horizon closed loops with any adapter: the example the CLI,
notebook, tests and benchmark run.

At every time t the tool's MPC plans ``horizon`` stages from the current
belief (warm started with the shifted previous plan; the first solve from
:meth:`BeliefMPC.guess` of a safe reference, certificates included), the
first step is applied to the plant (:meth:`BeliefMPC.apply`), and that
transition is checked *exactly* (Theorem 1 by :mod:`belief_nlp.geometry`,
target containment at the last step). A step that fails the check -- or a
solve that fails -- is replaced by the next step of the last accepted plan
(the usual MPC fallback) or else by staying put with exact certificates
(:meth:`BeliefMPC.hold`), each checked exactly too;
``meta["fallback_steps"]`` counts them. The result is a
:class:`~belief_nlp.BeliefPath` of the applied beliefs.
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from ..errors import SolverError, ValidationError
from ..path import BeliefPath
from ..scenario import Scenario
from .bundle import _scenario
from .kit import BeliefMPC, reference_path

__all__ = ["closed_loop", "TOOLS", "make_solver", "PROX"]

#: default proximal weight of the closed loops (docs/mpc.md, "Speed")
PROX = 1.0


def _opti(kit: BeliefMPC, horizon: int):
    from .opti import OptiMPC

    return OptiMPC(kit, horizon, warm_duals=True)


def _dompc(kit: BeliefMPC, horizon: int):
    from .dompc import DompcMPC

    return DompcMPC(kit, horizon)


def _rockit(kit: BeliefMPC, horizon: int):
    from .rockit import RockitMPC

    return RockitMPC(kit, horizon)


#: tool name -> factory(kit, horizon) of an object with solve(state, t, steps, ref, guess) -> (nu, N) plan
TOOLS: dict[str, Callable] = {"opti": _opti, "dompc": _dompc, "rockit": _rockit}


def make_solver(tool: str, kit: BeliefMPC, horizon: int):
    """The MPC of ``tool`` ("opti", "dompc", "rockit") for ``kit``."""
    if tool not in TOOLS:
        raise ValidationError("tool", f"must be one of {sorted(TOOLS)}, got {tool!r}")
    return TOOLS[tool](kit, horizon)


def _step_safe(kit: BeliefMPC, hazards, x, P, x1, P1, final: bool, levels=None) -> bool:
    """The transition clears every hazard at its level (``levels`` (J,), default
    the scenario's chi2) and, at the last step, the final ellipse is in the target."""
    from ..geometry import containment_margin, transition_clearances

    sc = kit.scenario
    lv = sc.chi2 if levels is None else levels
    ok = float(np.min(transition_clearances(x[None], P[None], x1[None], sc.W, hazards, lv))) >= 0
    if ok and final:
        ok = float(np.min(containment_margin(x1, P1, sc.target.A, sc.target.b, sc.chi2))) >= 0
    return ok


def closed_loop(scenario: Scenario | str, tool: str = "opti", horizon: int = 10, steps: int | None = None,
                reference: BeliefPath | None = None, alpha: float | None = None, track: float = 10.0,
                seed: int = 0, progress: Callable[[int, float], None] | None = None,
                prox: float = PROX, levels: np.ndarray | None = None) -> BeliefPath:
    """Run the belief MPC of ``tool`` for ``steps`` steps (default: the
    reference's transitions; :func:`.reference_path` makes that the
    scenario's horizon K, else 20, or more when its plan has more edges)
    with prediction ``horizon``.

    ``reference``: a safe path of ``steps`` transitions to track and to warm
    start from (default :func:`.reference_path`, an IG-RRT* plan made
    feasible). ``prox``: weight of the proximal term toward the previous
    plan (:class:`BeliefMPC`). Returns the closed-loop BeliefPath (SI) with ``meta``: tool,
    horizon, steps, step_times (s), iterations, fallback_steps. Raises
    SolverError when a step can be neither solved nor taken from the last plan.
    """
    if tool not in TOOLS:
        raise ValidationError("tool", f"must be one of {sorted(TOOLS)}, got {tool!r}")
    sc = _scenario(scenario)
    for name, v in (("steps", steps), ("horizon", horizon)):
        if v is None and name == "steps":           # the reference's own count
            continue
        if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1:
            raise ValidationError(name, f"must be a positive integer, got {v!r}")
    kit = BeliefMPC.build(sc, alpha=alpha, track=track, prox=prox)
    ref = reference_path(sc, steps, seed=seed) if reference is None else reference
    steps = ref.K if steps is None else steps
    if ref.K != steps:
        raise ValidationError("reference", f"must have {steps} transitions, got {ref.K}")
    lv = None
    if levels is not None:
        lv = np.asarray(levels, float)
        if lv.shape != (steps, len(sc.hazards)) or not np.all(np.isfinite(lv)) or np.any(lv <= 0):
            raise ValidationError("levels", f"must be ({steps}, {len(sc.hazards)}) finite levels > 0, "
                                            f"got shape {lv.shape}")
        # stage rows >= margin at level lv: the plan keeps that margin beyond each level, so
        # IPOPT's tolerance (~1e-6) never lands a step below the level the exact check asks
        p_all = kit.stage.stage_params(np.vstack([lv, np.repeat(lv[-1:], horizon, axis=0)]))
    mpc = make_solver(tool, kit, horizon)
    hazards = kit.hazards                              # built once; hold() uses it too
    U = kit.guess(ref, extra=horizon, levels=lv)      # (nu, steps + horizon)
    x, P = sc.x0.copy(), sc.P0.copy()
    xs, Ss, times, iters = [x], [], [], []
    tail: list[np.ndarray] = []
    fallbacks = 0
    for t in range(steps):
        guess = U[:, t:t + horizon]
        t0 = time.perf_counter()
        try:
            extra = {} if lv is None else {"p": p_all[:, t:t + horizon]}
            plan = mpc.solve(kit.state(x, P), t, steps, kit.references(ref, guess, t, horizon), guess, **extra)
        except SolverError:
            plan = None
        times.append(time.perf_counter() - t0)
        iters.append(int(getattr(mpc, "last_stats", {}).get("iter_count", -1)))
        step = None
        if plan is not None:
            x1, P1, S = kit.apply(x, P, plan[:, 0])
            if _step_safe(kit, hazards, x, P, x1, P1, t == steps - 1, None if lv is None else lv[t]):
                step, tail = (x1, P1, S), [plan[:, k] for k in range(1, horizon)]
                U[:, t:t + horizon] = plan
                if t + horizon < U.shape[1] and t + horizon < steps:   # a feasible stage for the shifted guess
                    U[:, t + horizon] = kit.hold(kit.rollout(kit.state(x, P), plan)[:, -1], plan[:, -1])
        if step is None:                           # the last plan's next step, else stay put -- checked exactly
            hold = kit.hold(kit.state(x, P), tail[0] if tail else U[:, t])
            for v in tail[:1] + [hold]:
                x1, P1, S = kit.apply(x, P, v)
                if _step_safe(kit, hazards, x, P, x1, P1, t == steps - 1, None if lv is None else lv[t]):
                    step, fallbacks, U[:, t] = (x1, P1, S), fallbacks + 1, v
                    break
            tail = tail[1:]
            if step is None:
                raise SolverError(f"{tool}: step {t + 1} could not be solved safely and no certified step is left")
        x, P, S = step
        xs.append(x)
        Ss.append(S)
        if progress is not None:
            progress(t, times[-1])
    return BeliefPath.from_sensing(np.array(xs), sc.P0, np.array(Ss), W=sc.W, noise="per_step",
                                   meta={"method": f"mpc_{tool}", "scenario": sc.name, "tool": tool,
                                         "horizon": int(horizon), "steps": int(steps), "alpha": kit.alpha,
                                         "step_times": times, "iterations": iters,
                                         "fallback_steps": fallbacks})
