"""``belief-nlp scenarios``: list the built-in scenarios, show, export or draw one."""

from __future__ import annotations

from pathlib import Path

from ..errors import ValidationError
from .common import EXIT_OK, _Run
from .figures import _save_and_close
from .parser import _output_args


def add_parser(sub) -> None:
    """Add the ``scenarios`` subcommand to the subparsers ``sub``."""
    sp = sub.add_parser(
        "scenarios", help="list built-in scenarios, show, export or draw one",
        description="Without NAME: list the built-in scenarios. With NAME (a built-in or a file): print its "
                    "contents; --export writes it as TOML/JSON (a starting point for your own scenario), "
                    "--plot draws it.",
        epilog="Examples:\n  belief-nlp scenarios\n  belief-nlp scenarios paper-multi --export my.toml\n"
               "  belief-nlp scenarios my.toml --plot my.png")
    sp.add_argument("name", nargs="?", help="built-in name or scenario file")
    sp.add_argument("--export", type=Path, metavar="FILE", help="write the scenario to this .toml or .json file")
    sp.add_argument("--plot", type=Path, metavar="FILE", help="draw the scenario into this image (.png, .pdf, .svg)")
    _output_args(sp, out_default=None)
    sp.set_defaults(func=_cmd_scenarios)


def _cmd_scenarios(run: _Run) -> int:
    from ..scenario import list_scenarios, load_scenario, save_scenario

    a = run.args
    if a.name is None:
        if a.export or a.plot:
            raise ValidationError("name", "--export and --plot need a scenario NAME")
        for name in list_scenarios():
            sc = load_scenario(name)
            print(f"{name:12s} {sc.dim}-D, {len(sc.obstacles)} obstacles  {sc.description}")
        return EXIT_OK
    sc = load_scenario(a.name)
    if a.export is not None:
        save_scenario(sc, a.export)
        run.say(f"wrote {a.export}")
    if a.plot is not None:
        from ..plotting import plot_scenario

        fig, ax = plot_scenario(sc, annotate=True)
        ax.set_title(sc.name or str(a.name), fontsize=9)
        _save_and_close(fig, a.plot)
        run.say(f"wrote {a.plot}")
    if a.export is None and a.plot is None:
        print(_describe_scenario(sc))
    return EXIT_OK


def _describe_scenario(sc) -> str:
    import numpy as np

    def arr(v) -> str:
        v = np.asarray(v, dtype=float)
        if v.ndim == 0:
            return f"{float(v):.4g}"
        return "[" + ", ".join(arr(row) for row in v) + "]"

    conf = (f"confidence {sc.confidence:g} (chi2 = {sc.chi2:.5g})" if sc.confidence is not None
            else f"chi2 = {sc.chi2:.5g}")
    lines = [f"{sc.name or 'scenario'}: {sc.description}" if sc.description else (sc.name or "scenario"),
             f"  dimension     {sc.dim}",
             f"  domain        {arr(sc.domain.bounding_box()[0])} .. {arr(sc.domain.bounding_box()[1])} "
             f"({sc.domain.A.shape[0]} faces)",
             f"  target        {arr(sc.target.bounding_box()[0])} .. {arr(sc.target.bounding_box()[1])} "
             f"({sc.target.A.shape[0]} faces)",
             f"  start         x0 = {arr(sc.x0)}, P0 = {arr(sc.P0)}"
             + ("" if sc.start_confidence is None else
                f", held to confidence {sc.start_confidence:g} (chi2 = {sc.chi2_start:.5g}) with transition 1"),
             f"  noise         W = {arr(sc.W)} per step, W_rate = {arr(sc.W_rate)} per metre",
             f"  alpha         {sc.alpha:g}",
             f"  ellipses      {conf}",
             f"  horizon K     {sc.K if sc.K is not None else '(one step per path edge)'}",
             f"  planner       {sc.planner or '{}'}",
             f"  obstacles     {len(sc.obstacles)}"]
    for ob in sc.obstacles:
        lines.append(f"    {ob.name}: {ob.vertices.shape[0]} vertices, "
                     f"{arr(ob.vertices.min(axis=0))} .. {arr(ob.vertices.max(axis=0))}")
    return "\n".join(lines)
