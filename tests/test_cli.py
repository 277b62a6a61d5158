"""The belief-nlp command line: every subcommand on a small setting, its files,
its exit codes and its one-line errors."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.cli import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_OK, main

from conftest import paper_multi_path_pair

SUBCOMMANDS = ("scenarios", "plan", "smooth", "compare", "demo")


# ------------------------------------------------------------------ helpers
def assert_image(path: Path, min_side: int = 100) -> np.ndarray:
    """A real picture: a PNG that decodes, of some size, not one flat colour."""
    import matplotlib.image as mpimg

    assert path.is_file(), f"{path} was not written"
    assert path.stat().st_size > 5_000, f"{path} is suspiciously small ({path.stat().st_size} bytes)"
    img = mpimg.imread(path)
    assert img.ndim == 3 and min(img.shape[:2]) >= min_side, img.shape
    assert float(np.std(img[..., :3])) > 0.02, f"{path} is (nearly) one flat colour"
    return img


def gif_frames(path: Path) -> int:
    from PIL import Image

    assert path.is_file() and path.stat().st_size > 5_000
    with Image.open(path) as im:
        return im.n_frames


def run(argv, capsys):
    """main(argv) in-process; returns (exit code, stdout, stderr)."""
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(err: str) -> None:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, f"expected a one-line message, got:\n{err}"
    assert "Traceback" not in err
    assert lines[0].startswith("belief-nlp")


def resaved_equal(obj, cls, folder: Path, name: str) -> None:
    """Saving a loaded result again and loading it gives the same document."""
    again = cls.load(obj.save(folder / name))
    assert json.dumps(again.to_dict(), sort_keys=True) == json.dumps(obj.to_dict(), sort_keys=True)


@pytest.fixture(scope="module")
def hand_path_file(tmp_path_factory):
    """A feasible 10-step path through paper-multi, saved as JSON."""
    _, path = paper_multi_path_pair(steps_per_segment=2)
    return path.save(tmp_path_factory.mktemp("input") / "hand.json")


# -------------------------------------------------------------------- help
@pytest.mark.parametrize("cmd", [(), *((c,) for c in SUBCOMMANDS)])
def test_help_everywhere(cmd, capsys):
    code, out, _ = run([*cmd, "--help"], capsys)
    assert code == EXIT_OK
    assert out.startswith("usage: belief-nlp")
    if cmd:
        assert "--out" in out or cmd == ("scenarios",)


def test_top_level_help_lists_every_command_and_exit_code(capsys):
    """The description's summary names every subcommand the parser has, and
    the epilog every exit code main() can return."""
    from belief_nlp.cli import build_parser

    code, out, _ = run(["--help"], capsys)
    sub = next(a for a in build_parser()._actions if a.__class__.__name__ == "_SubParsersAction")
    summary = out.split("positional arguments")[0]
    for name in sub.choices:
        assert f"  {name} " in summary, name
    for text in ("0 success", "2 bad input", "3 planning or solving failed", "1 internal"):
        assert text in " ".join(out.split())


# --------------------------------------------------------------- scenarios
def test_scenarios_list_show_export_plot(tmp_path, capsys):
    code, out, _ = run(["scenarios"], capsys)
    assert code == EXIT_OK
    assert all(name in out for name in bn.list_scenarios())

    code, out, _ = run(["scenarios", "paper-multi"], capsys)
    assert code == EXIT_OK and "obstacle 6" in out and "chi2 = 4.605" in out

    for suffix in (".toml", ".json"):
        f = tmp_path / f"exported{suffix}"
        code, out, _ = run(["scenarios", "paper-multi", "--export", f], capsys)
        assert code == EXIT_OK and f"wrote {f}" in out
        assert bn.load_scenario(f) == bn.load_scenario("paper-multi")
    # a scenario file works wherever a name does
    code, out, _ = run(["scenarios", tmp_path / "exported.toml", "--plot", tmp_path / "sc.png"], capsys)
    assert code == EXIT_OK
    assert_image(tmp_path / "sc.png")


# -------------------------------------------------------------------- plan
def test_plan_writes_reloadable_results_and_figures(tmp_path, capsys):
    from belief_nlp.planner import PlanResult

    out_dir = tmp_path / "plan"
    code, out, err = run(["plan", "quad", "--nodes", 150, "--seed", 0, "--alpha", 0.2, "--out", out_dir], capsys)
    assert code == EXIT_OK, err
    assert "plan: planner cost" in out
    assert "IG-RRT*" in err  # progress on stderr
    res = PlanResult.load(out_dir / "plan.json")
    assert res.success and res.path is not None and res.alpha == 0.2
    assert len(res.cost_history) == 150 and res.tree is not None
    resaved_equal(res, PlanResult, tmp_path, "again.json")
    assert_image(out_dir / "plan.png")
    assert_image(out_dir / "plan_cost.png")

    # NPZ and --quiet: nothing on stdout or stderr, same plan (same seed)
    code, out, err = run(["plan", "quad", "--nodes", 150, "--alpha", 0.2, "--format", "npz", "--quiet",
                          "--out", out_dir], capsys)
    assert code == EXIT_OK and out == "" and err == ""
    npz = PlanResult.load(out_dir / "plan.npz")
    assert np.array_equal(npz.path.x, res.path.x) and np.array_equal(npz.path.P, res.path.P)
    assert npz.cost == res.cost
    resaved_equal(npz, PlanResult, tmp_path, "again.npz")


def test_plan_failure_exits_3_with_the_reason(tmp_path, capsys):
    code, _, err = run(["plan", "paper-multi", "--nodes", 2, "-q", "--out", tmp_path], capsys)
    assert code == EXIT_FAILED
    assert_one_line_error(err)
    assert "planning failed" in err and "no path" in err
    # the (failed) result is still written for inspection
    from belief_nlp.planner import PlanResult

    assert not PlanResult.load(tmp_path / "plan.json").success


# ------------------------------------------------------------------ smooth
def test_smooth_from_a_path_file(tmp_path, hand_path_file, capsys):
    code, out, err = run(["smooth", "paper-multi", "--path", hand_path_file, "--method", "ccp", "--max-iter", 3,
                          "--gif", "--format", "npz", "--out", tmp_path], capsys)
    assert code == EXIT_OK, err
    assert "max_iter" in out and "CCP" in err
    res = bn.SmoothResult.load(tmp_path / "smooth.json")
    assert res.method == "ccp" and res.nit == 3 and res.safe
    assert res.path.K == 20  # paper-multi's [horizon] K; the hand path has 10 edges
    assert res.cost < res.initial_cost
    assert bn.BeliefPath.load(tmp_path / "smoothed_path.npz") == res.path
    assert bn.verify(bn.load_scenario("paper-multi"), res.path).safe
    resaved_equal(res, bn.SmoothResult, tmp_path, "again.json")
    assert_image(tmp_path / "smooth.png")
    assert_image(tmp_path / "smooth_cost.png")
    assert gif_frames(tmp_path / "smoothing.gif") == 4  # the start + 3 iterations

    # a smoothing result is itself a valid input, with another horizon
    code, _, err = run(["smooth", "paper-multi", "--path", tmp_path / "smooth.json", "-K", 24, "--max-iter", 1,
                        "--alpha", 1.0, "-q", "--out", tmp_path / "again"], capsys)
    assert code == EXIT_OK, err
    again = bn.SmoothResult.load(tmp_path / "again" / "smooth.json")
    assert again.path.K == 24 and again.alpha == 1.0


def test_smooth_defaults_to_auto(tmp_path, hand_path_file, capsys):
    """Without --method the CLI smooths with bn.DEFAULT_METHOD, auto: IPOPT,
    CCP as its fallback; the result, the figures and the GIF say which ran."""
    from belief_nlp.cli import build_parser

    assert build_parser().parse_args(["smooth", "paper-multi"]).method == bn.DEFAULT_METHOD == "auto"
    code, out, err = run(["smooth", "paper-multi", "--path", hand_path_file, "-K", 10, "--gif", "--out", tmp_path],
                         capsys)
    assert code == EXIT_OK, err
    res = bn.SmoothResult.load(tmp_path / "smooth.json")
    assert res.method.startswith("auto") and res.stats["stages"][0] == "ipopt"
    assert res.safe and res.cost <= res.initial_cost and res.path.K == 10
    assert f"smooth: {res.method}: {res.status}" in out
    assert_image(tmp_path / "smooth.png")
    assert_image(tmp_path / "smooth_cost.png")
    assert gif_frames(tmp_path / "smoothing.gif") >= 1


def test_smooth_plans_first_without_a_path(tmp_path, capsys):
    code, out, err = run(["smooth", "paper-multi", "--nodes", 150, "--max-iter", 2, "--noise", "per_step",
                          "-q", "--out", tmp_path], capsys)
    if code == EXIT_FAILED and "planning failed" in err:
        pytest.skip(f"the planner found no path at this small setting: {err.strip()}")
    assert code in (EXIT_OK, EXIT_FAILED), err
    from belief_nlp.planner import PlanResult

    plan = PlanResult.load(tmp_path / "plan.json")
    assert plan.success
    if code == EXIT_OK:
        res = bn.SmoothResult.load(tmp_path / "smooth.json")
        assert res.path.K == max(20, plan.path.K)  # the scenario's horizon unless the plan has more edges
        assert res.cost <= res.initial_cost
        assert_image(tmp_path / "smooth.png")
    else:
        assert_one_line_error(err)


@pytest.mark.skipif(importlib.util.find_spec("belief_nlp.methods.ipopt") is None,
                    reason="belief_nlp.methods.ipopt (the IPOPT method) is not in this tree yet")
def test_smooth_with_ipopt(tmp_path, hand_path_file, capsys):
    code, out, err = run(["smooth", "paper-multi", "--path", hand_path_file, "--method", "ipopt",
                          "--max-iter", 200, "-q", "--out", tmp_path], capsys)
    assert code in (EXIT_OK, EXIT_FAILED), err
    res = bn.SmoothResult.load(tmp_path / "smooth.json")
    assert res.method == "ipopt" and res.safe
    if code == EXIT_FAILED:
        assert_one_line_error(err)
        assert res.status in err


# ----------------------------------------------------------------- compare
@pytest.mark.skipif(importlib.util.find_spec("belief_nlp.comparison") is None,
                    reason="belief_nlp.comparison is not in this tree yet")
def test_compare_writes_records_table_and_figures(tmp_path, hand_path_file, capsys):
    code, out, err = run(["compare", "paper-multi", "--path", hand_path_file, "--methods", "ccp", "ipopt",
                          "--max-iter", 400, "--format", "npz", "--out", tmp_path], capsys)
    assert code == EXIT_OK, err
    records = json.loads((tmp_path / "compare.json").read_text())
    assert [r["method"] for r in records] == ["ccp", "ipopt"]
    table = (tmp_path / "compare.txt").read_text()
    assert "ccp" in table and "ipopt" in table and table.strip() in out
    for rec in records:
        assert rec["K"] == 20 and rec["history"] and rec["status"] != "error", rec["message"]
        path = bn.BeliefPath.load(tmp_path / f"compare_path_{rec['method']}.npz")
        assert path == bn.BeliefPath.from_dict(rec["path"])
        assert bn.verify(bn.load_scenario("paper-multi"), path).safe == rec["safe"] is True
    assert_image(tmp_path / "compare.png")
    assert_image(tmp_path / "compare_cost.png")


# -------------------------------------------------------------------- demo
def _console_script() -> list[str]:
    found = shutil.which("belief-nlp") or str(Path(sys.executable).with_name("belief-nlp"))
    if not Path(found).is_file():
        pytest.fail("the belief-nlp console script is not installed (pip install -e '.[test]')")
    return [found]


@pytest.mark.parametrize("method", [None, "ccp"], ids=["default-auto", "ccp"])
def test_demo_quick_through_the_console_script(tmp_path, method):
    """The README's first command, in small: figures, GIFs and reloadable
    results; by default smoothed by auto (run to its own limit), and with
    --method ccp by the paper's CCP (--quick: 3 iterations)."""
    from belief_nlp.planner import PlanResult

    out_dir = tmp_path / "demo out"
    env = dict(os.environ, MPLBACKEND="Agg")
    extra = [] if method is None else ["--method", method]
    proc = subprocess.run([*_console_script(), "demo", "--quick", *extra, "--out", str(out_dir)],
                          capture_output=True, text=True, env=env, timeout=600, cwd=tmp_path)
    assert "Traceback" not in proc.stderr, proc.stderr
    summary = json.loads((out_dir / "summary.json").read_text())
    assert [r["alpha"] for r in summary["runs"]] == [0.1, 1.0]
    assert summary["method"] == (method or "auto")
    # ccp: the paper's cap, 3 at --quick; auto: its own limit (it runs until converged)
    assert summary["max_iter"] == (3 if method == "ccp" else bn.get_method("auto").max_iter)
    for name in ("fig2_planner_paths.png", "fig3_smoothed_paths.png", "fig4_cost_history.png"):
        assert_image(out_dir / name)
    if proc.returncode == EXIT_FAILED:
        # only planning may fail at the quick setting; it is reported, not hidden
        assert summary["failures"] and "failed" in proc.stderr
    else:
        assert proc.returncode == EXIT_OK, proc.stderr
    done = [r for r in summary["runs"] if r.get("smooth_status")]
    assert done, f"no alpha got through the quick demo: {summary['failures']}"
    for r in done:
        tag = f"alpha{r['alpha']:g}"
        plan = PlanResult.load(out_dir / f"plan_{tag}.json")
        res = bn.SmoothResult.load(out_dir / f"smooth_{tag}.json")
        assert res.path == bn.BeliefPath.load(out_dir / f"smoothed_path_{tag}.json")
        assert res.nit <= summary["max_iter"] and res.cost <= res.initial_cost and res.alpha == r["alpha"]
        assert plan.success and r["plan_cost"] == plan.cost
        assert res.method == r["smooth_method"] and f"{res.method} {res.status} after {res.nit}" in proc.stdout
        assert gif_frames(out_dir / f"smoothing_{tag}.gif") == r["gif_frames"] >= 1
        if method == "ccp":
            assert res.method == "ccp" and res.nit <= 3
            assert gif_frames(out_dir / f"smoothing_{tag}.gif") == len(r["cost_history"])
        else:
            assert res.method.startswith("auto")
    assert "demo finished" in proc.stdout


def test_demo_in_process_single_alpha(tmp_path, hand_path_file, capsys):
    from belief_nlp.cli.demo import DEMO_MAX_RADIUS
    from belief_nlp.planner import PlanResult

    code, out, err = run(["demo", "--quick", "--method", "ccp", "--alphas", 0.1, "--no-gif", "--nodes", 200,
                          "--out", tmp_path], capsys)
    assert code == EXIT_OK or (code == EXIT_FAILED and "planning failed" in err), err
    assert sorted(p.name for p in tmp_path.glob("*.gif")) == []
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["nodes"] == 200 and summary["max_iter"] == 3 and summary["method"] == "ccp"
    assert_image(tmp_path / "fig4_cost_history.png")
    # the demo's radius cap is its own (1.5), not paper-multi's 0.3: its log line says so ...
    assert DEMO_MAX_RADIUS == 1.5 and summary["max_radius"] == 1.5
    assert ("200 nodes, seed 0, alpha 0.1, per_step noise, radius cap 1.5 + 1.2 alpha = 1.62 (--max-radius; "
            "the scenario's [planner]: 0.3 + 1.2 alpha)") in err
    # ... and 'plan' with the settings the log states plans the same path; without them, its own
    for i, (extra, note) in enumerate(((["--max-radius", 1.5], "1.62 (--max-radius;"),
                                       ([], "radius cap 0.3 + 1.2 alpha = 0.42\n"))):
        code, _, err = run(["plan", "paper-multi", "--alpha", 0.1, "--nodes", 200, *extra,
                            "--out", tmp_path / f"p{i}"], capsys)
        assert note in err
    same = PlanResult.load(tmp_path / "plan_alpha0.1.json"), PlanResult.load(tmp_path / "p0" / "plan.json")
    assert same[0].cost == same[1].cost is not None
    if same[0].success:
        assert same[0].path == same[1].path
    assert "demo's own, not the scenario's [planner] value" in " ".join(
        run(["demo", "--help"], capsys)[1].split())


def test_plans_log_the_cap_of_their_noise_model(tmp_path, capsys):
    """quad keeps the authors' per-metre noise (no growth of the cap with
    alpha); 'plan' uses per-step noise, under which the cap grows by default:
    the log states the cap the planner used, and the plan is found."""
    for noise, note in (("per_step", "radius cap 0.5 + 1.2 alpha = 1.7\n"), ("per_metre", "radius cap 0.5\n")):
        code, _, err = run(["plan", "quad", "--alpha", 1.0, "--nodes", 300, "--noise", noise,
                            "--out", tmp_path / noise], capsys)
        assert code == EXIT_OK and note in err, err


@pytest.mark.parametrize("argv, max_iter", [
    ([], None), (["--quick"], None), (["--converged"], None), (["--max-iter", "7"], 7),
    (["--method", "ipopt", "--quick"], None),
    (["--method", "ccp"], 15), (["--method", "ccp", "--quick"], 3), (["--method", "ccp", "--converged"], 200),
    (["--method", "ccp", "--quick", "--converged"], 200), (["--method", "ccp", "--quick", "--max-iter", "9"], 9),
])
def test_demo_iteration_limit(argv, max_iter):
    """The demo smooths with auto by default, to the method's own limit (None);
    the paper's 15 CCP iterations (--quick 3, --converged 200) apply to
    --method ccp; --max-iter always wins."""
    from belief_nlp.cli import build_parser
    from belief_nlp.cli.demo import _demo_max_iter

    args = build_parser().parse_args(["demo", *argv])
    assert args.method == (argv[argv.index("--method") + 1] if "--method" in argv else "auto")
    assert _demo_max_iter(args) == max_iter


# -------------------------------------------------------------- bad input
def _bad_files(tmp_path: Path) -> dict[str, Path]:
    malformed = tmp_path / "malformed.toml"
    malformed.write_text("this is = not [ toml")
    unknown_key = tmp_path / "unknown.json"
    data = bn.load_scenario("tutorial").to_dict()
    data["colour"] = "red"
    unknown_key.write_text(json.dumps(data))
    not_a_path = tmp_path / "notapath.json"
    not_a_path.write_text(json.dumps({"x": [[0, 0]]}))
    a_file = tmp_path / "a_file"
    a_file.write_text("")
    return {"malformed": malformed, "unknown": unknown_key, "notapath": not_a_path, "afile": a_file}


BAD_INPUTS = [
    (["frobnicate"], "invalid choice"),
    ([], "required"),
    (["plan"], "required: scenario"),
    (["plan", "no-such-scenario"], "unknown scenario"),
    (["plan", "{tmp}/missing.toml"], "no such scenario file"),
    (["plan", "{malformed}"], "malformed TOML"),
    (["plan", "{unknown}"], "colour"),
    (["plan", "quad", "--nodes", "0"], "--nodes"),
    (["plan", "quad", "--nodes", "many"], "--nodes"),
    (["plan", "quad", "--alpha", "-1"], "--alpha"),
    (["plan", "quad", "--time-limit", "nan"], "--time-limit"),
    (["plan", "quad", "--colour", "red"], "unrecognized arguments"),
    (["plan", "quad", "--out", "{afile}"], "not a folder"),
    (["smooth", "paper-multi", "--path", "{tmp}/missing.json"], "no such file"),
    (["smooth", "paper-multi", "--path", "{malformed}"], "malformed JSON"),
    (["smooth", "paper-multi", "--path", "{notapath}"], "path"),
    (["smooth", "paper-multi", "--method", "newton"], "invalid choice"),
    (["smooth", "paper-multi", "--path", "{hand}", "-K", "3"], "K"),
    (["scenarios", "nope"], "unknown scenario"),
    (["scenarios", "quad", "--export", "{tmp}/quad.yaml"], ".toml or .json"),
    (["demo", "--alphas", "x"], "--alphas"),
    (["demo", "--method", "newton"], "invalid choice"),
    (["demo", "--scenario", "{tmp}/missing.json"], "no such scenario file"),
]


@pytest.mark.parametrize("argv, words", BAD_INPUTS, ids=[" ".join(a) or "(nothing)" for a, _ in BAD_INPUTS])
def test_bad_input_exits_2_with_one_line(argv, words, tmp_path, hand_path_file, capsys):
    files = {k: str(v) for k, v in _bad_files(tmp_path).items()}
    argv = [a.format(tmp=tmp_path, hand=hand_path_file, **files) for a in argv]
    if argv and argv[0] not in ("scenarios",) and "--out" not in argv and argv[0] in SUBCOMMANDS:
        argv += ["--out", str(tmp_path / "out")]
    code, out, err = run(argv, capsys)
    assert code == EXIT_BAD_INPUT, (out, err)
    assert_one_line_error(err)
    assert words in err


def test_bad_input_through_the_console_script(tmp_path):
    proc = subprocess.run([*_console_script(), "smooth", "paper-multi", "--path", str(tmp_path / "nope.json"),
                           "--out", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == EXIT_BAD_INPUT
    assert_one_line_error(proc.stderr)
    assert "no such file" in proc.stderr and proc.stdout == ""
    proc = subprocess.run([*_console_script(), "plan", "quad", "--nodes", "-5"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == EXIT_BAD_INPUT
    assert_one_line_error(proc.stderr)


def test_an_internal_error_is_one_line_with_a_hint(monkeypatch, capsys):
    """A bug of ours exits 1 with one line and a hint; -v adds the traceback."""
    import belief_nlp.cli.scenarios as scen

    def boom(run):
        raise RuntimeError("something broke\nover two lines")

    monkeypatch.setattr(scen, "_cmd_scenarios", boom)
    from belief_nlp.cli import main

    assert main(["scenarios"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "internal error" in err and "-v" in err and "Traceback" not in err
    assert main(["scenarios", "-v"]) == 1
    assert "Traceback" in capsys.readouterr().err


def test_log_lines_go_through_tqdm_on_a_terminal(tmp_path, capsys, monkeypatch):
    """With a progress bar possible (a terminal), -v log lines are written by
    tqdm (they would otherwise break the live bar) and still reach stderr."""
    import belief_nlp._progress as progress
    from tqdm import tqdm

    writes = []
    real = tqdm.write
    monkeypatch.setattr(progress, "_interactive", lambda: True)
    monkeypatch.setattr(tqdm, "write", classmethod(lambda cls, s, *a, **k: (writes.append(s), real(s, *a, **k))))
    code, _, err = run(["plan", "paper-multi", "--nodes", 300, "-v", "--out", tmp_path], capsys)
    assert code == 0, err
    assert writes and all(w in err for w in writes)
