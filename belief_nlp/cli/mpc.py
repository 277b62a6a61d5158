"""``belief-nlp mpc``: a receding-horizon belief-space MPC with casadi.Opti, do-mpc or rockit."""

from __future__ import annotations

from .common import EXIT_FAILED, EXIT_OK, _load_scenario, _Run
from .figures import _panels, _save_fig
from .parser import _output_args, _positive_int, _scenario_arg


def add_parser(sub) -> None:
    """Add the ``mpc`` subcommand to the subparsers ``sub``."""
    mp = sub.add_parser(
        "mpc", help="run a receding-horizon belief MPC (casadi.Opti, do-mpc or rockit) with the safety bundles",
        description="Run the closed loop of belief_nlp.export.closed_loop: at every step the chosen tool's MPC "
                    "plans --horizon stages with the Theorem-1 safety bundle and the target bundle, the first "
                    "step is applied and checked exactly. Writes OUT/closed_loop.json (BeliefPath.load reads "
                    "it: applied means, prior and posterior covariances, sensing) and OUT/closed_loop.png. "
                    "Exit 0 when the loop reached the target safely (belief_nlp.verify), 3 otherwise. The "
                    "do-mpc and rockit tools need pip install -e '.[mpc]'.",
        epilog="Example:\n  belief-nlp mpc paper-multi --tool opti --horizon 10 --steps 20 --out out_mpc")
    _scenario_arg(mp)
    mp.add_argument("--tool", choices=("opti", "dompc", "rockit"), default="opti", help="the MPC tool")
    mp.add_argument("--horizon", type=_positive_int, default=10, help="prediction horizon (stages)")
    mp.add_argument("--steps", type=_positive_int, default=None,
                    help="closed-loop steps (default: the scenario's horizon K, else 20; more when the reference "
                         "plan has more edges)")
    mp.add_argument("--seed", type=int, default=0, help="seed of the IG-RRT* reference")
    _output_args(mp)
    mp.set_defaults(func=_cmd_mpc)


def _cmd_mpc(run: _Run) -> int:
    import numpy as np

    from ..errors import SolverError
    from ..export.closed_loop import closed_loop
    from ..plotting import plot_belief_path
    from ..verify import verify

    a = run.args
    sc = _load_scenario(a.scenario, a.alpha)
    run.prepare_out()
    try:
        path = closed_loop(sc, a.tool, horizon=a.horizon, steps=a.steps, seed=a.seed)
    except SolverError as exc:
        print(f"belief-nlp mpc: failed: {exc}", file=__import__("sys").stderr)
        return EXIT_FAILED
    run.wrote(path.save(run.out / "closed_loop.json"))
    report = verify(sc, path)
    fig, axes = _panels(1, sc.dim)
    plot_belief_path(sc, path, ax=axes[0], legend=sc.dim == 2)
    times = np.asarray(path.meta["step_times"])
    axes[0].set_title(f"{a.tool} MPC, horizon {a.horizon}: {path.K} steps, median step {1e3 * np.median(times):.0f} "
                      f"ms, {'safe' if report.safe else 'NOT safe'}", fontsize=9)
    _save_fig(run, fig, "closed_loop.png")
    run.say(f"{a.tool}: {path.K} steps, median step {1e3 * np.median(times):.1f} ms, max {1e3 * times.max():.1f} ms, "
            f"fallback steps {path.meta['fallback_steps']}; {report.summary()}")
    run.list_written()
    return EXIT_OK if report.safe else EXIT_FAILED
