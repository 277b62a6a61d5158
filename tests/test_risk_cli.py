"""``belief-nlp plan|smooth --risk``: the budget on the command line and in
scenario files, its report, and one-line errors (issue 20, item 3)."""

from __future__ import annotations

import re

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.cli import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_OK, main
from belief_nlp.planner import PlanResult
from belief_nlp.risk import path_risk

NODES = "200"


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(err: str, *words: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith("belief-nlp")
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


def test_plan_with_a_budget_reports_the_certified_bound(tmp_path, capsys):
    code, out, err = run(["plan", "paper-multi", "--nodes", NODES, "--risk", "0.05", "--out", tmp_path], capsys)
    assert code == EXIT_OK, err
    line = next(line for line in out.splitlines() if "risk budget" in line)
    shown = float(re.search(r"certified collision bound ([0-9.e-]+)", line).group(1))
    res = PlanResult.load(tmp_path / "plan.json")
    bound = path_risk(bn.load_scenario("paper-multi"), res.path).step_time       # recomputed from the file
    assert bound <= 0.05 and shown == pytest.approx(bound, rel=5e-3)
    assert "risk budget 0.05" in line and res.risk["budget"] == 0.05


@pytest.mark.parametrize("value", ["0", "0.5", "0.7", "-0.01", "nan", "inf", "abc", ""])
@pytest.mark.parametrize("command", ["plan", "smooth"])
def test_bad_budgets_are_one_line_errors(tmp_path, capsys, command, value):
    code, out, err = run([command, "paper-multi", "--risk", value, "--out", tmp_path], capsys)
    assert code == EXIT_BAD_INPUT
    one_line_error(err, "--risk", "between 0 and 0.5")
    assert not (tmp_path / "plan.json").exists()


def test_scenario_file_budget_is_the_default(tmp_path, capsys):
    sc = bn.load_scenario("paper-multi").with_options(risk=0.1)
    file = bn.save_scenario(sc, tmp_path / "budget.toml")
    code, out, err = run(["plan", file, "--nodes", NODES, "--out", tmp_path / "a"], capsys)
    assert code == EXIT_OK, err
    assert "risk budget 0.1:" in out
    assert PlanResult.load(tmp_path / "a" / "plan.json").risk["budget"] == 0.1
    # --risk overrides the file's
    code, out, err = run(["plan", file, "--nodes", NODES, "--risk", "0.02", "--out", tmp_path / "b"], capsys)
    assert code == EXIT_OK and "risk budget 0.02:" in out


def test_budget_spent_by_the_start_is_bad_input(tmp_path, capsys):
    wide = bn.load_scenario("paper-multi").with_options(P0=2e-3 * np.eye(2))
    file = bn.save_scenario(wide, tmp_path / "wide.json")
    code, out, err = run(["plan", file, "--risk", "0.01", "--out", tmp_path], capsys)
    assert code == EXIT_BAD_INPUT
    one_line_error(err, "risk", "start belief")


def test_allocation_needs_a_budget(tmp_path, capsys):
    code, out, err = run(["smooth", "paper-multi", "--allocation", "uniform", "--out", tmp_path], capsys)
    assert code == EXIT_BAD_INPUT
    one_line_error(err, "--allocation", "risk budget")
    code, out, err = run(["smooth", "paper-multi", "--risk", "0.05", "--allocation", "even"], capsys)
    assert code == EXIT_BAD_INPUT
    one_line_error(err, "--allocation", "uniform")


def test_no_plan_within_the_budget_is_a_failure(tmp_path, capsys):
    code, out, err = run(["plan", "paper-multi", "--nodes", "2", "--risk", "0.05", "--out", tmp_path, "-q"], capsys)
    assert code == EXIT_FAILED
    one_line_error(err, "no plan within the risk budget 0.05", "--risk")


def test_smooth_with_a_budget(tmp_path, capsys):
    code, out, err = run(["smooth", "paper-multi", "--nodes", NODES, "--risk", "0.05", "--allocation", "uniform",
                          "--max-iter", "3", "--out", tmp_path], capsys)
    assert code == EXIT_OK, err
    line = next(line for line in out.splitlines() if line.startswith("smooth: risk budget"))
    assert "risk budget 0.05" in line and "uniform" in line
    smoothed = bn.BeliefPath.load(tmp_path / "smoothed_path.json")
    assert path_risk(bn.load_scenario("paper-multi"), smoothed).step_time <= 0.05
    assert (tmp_path / "smooth_risk.png").stat().st_size > 10_000


def test_risk_kind_needs_a_budget_and_is_named(tmp_path, capsys):
    code, out, err = run(["smooth", "paper-multi", "--risk-kind", "continuous", "--out", tmp_path], capsys)
    assert code == EXIT_BAD_INPUT
    one_line_error(err, "--risk-kind", "risk budget")
    code, out, err = run(["smooth", "paper-multi", "--risk", "0.05", "--risk-kind", "always"], capsys)
    assert code == EXIT_BAD_INPUT
    one_line_error(err, "--risk-kind", "continuous")


def test_smooth_with_a_continuous_budget(tmp_path, capsys):
    """The budget then limits the continuous-time bound of the smoothed path,
    recomputed here from the saved path."""
    code, out, err = run(["smooth", "paper-multi", "--nodes", "500", "--risk", "0.05", "--risk-kind", "continuous",
                          "--max-iter", "3", "--out", tmp_path], capsys)
    assert code == EXIT_OK, err
    line = next(line for line in out.splitlines() if line.startswith("smooth: risk budget"))
    assert "continuous" in line
    smoothed = bn.BeliefPath.load(tmp_path / "smoothed_path.json")
    assert path_risk(bn.load_scenario("paper-multi"), smoothed).continuous <= 0.05
