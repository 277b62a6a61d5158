"""The solvers' per-process log folders: removed at exit, and swept by the
next process when their own was killed before it could remove them."""

import os
import subprocess
import sys
import tempfile

import pytest

from belief_nlp.methods import solver_logs

pytestmark = pytest.mark.skipif(os.name != "posix", reason="the sweep probes processes with POSIX signal 0")


def _dead_pid() -> int:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def test_sweep_removes_dead_processes_folders_only(tmp_path):
    dead = tmp_path / f"belief_nlp_ipopt_{_dead_pid()}_abc"
    alive = tmp_path / f"belief_nlp_ipopt_{os.getpid()}_def"
    other_tag = tmp_path / f"belief_nlp_uno_{_dead_pid()}_ghi"
    legacy = tmp_path / "belief_nlp_ipopt_xyz"            # no process id: not ours to judge
    for d in (dead, alive, other_tag, legacy):
        d.mkdir()
        (d / "a.log").write_text("log")
    removed = solver_logs.sweep_stale("ipopt", root=str(tmp_path))
    assert removed == [str(dead)]
    assert not dead.exists() and alive.exists() and other_tag.exists() and legacy.exists()


def test_a_killed_process_folder_is_swept_by_the_next(tmp_path):
    # a real IPOPT smooth writes its log, then the process ends without its
    # atexit handlers (as a killed kernel or study worker does)
    code = ("import os, belief_nlp as bn\n"
            "from belief_nlp.methods.solver_logs import log_dir\n"
            "sc = bn.load_scenario('paper-multi')\n"
            "r = bn.smooth(sc, bn.plan(sc, n_nodes=150, seed=0), method='ipopt', K=8)\n"
            "d = log_dir('ipopt'); assert os.listdir(d), 'no log written'\n"
            "print(d, flush=True); os._exit(0)\n")
    env = {**os.environ, "TMPDIR": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    left = out.stdout.split()[-1]
    assert os.path.isdir(left) and os.path.dirname(left) == str(tmp_path)
    assert solver_logs.sweep_stale("ipopt", root=str(tmp_path)) == [left]
    assert not os.path.exists(left)


def test_log_dir_is_per_process_and_reused(monkeypatch, tmp_path):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.setattr(solver_logs, "_DIRS", {})
    first = solver_logs.log_dir("probe")
    assert first == solver_logs.log_dir("probe")
    assert os.path.basename(first).startswith(f"belief_nlp_probe_{os.getpid()}_")
    os.rmdir(first)                      # gone (e.g. removed by a parent after a fork): made anew
    assert os.path.isdir(solver_logs.log_dir("probe"))


@pytest.fixture(scope="module")
def small_case():
    import belief_nlp as bn
    sc = bn.load_scenario("paper-multi")
    return sc, bn.plan(sc, n_nodes=150, seed=0).path


def _logs() -> set:
    return set(os.listdir(solver_logs.log_dir("ipopt")))


def test_a_solvers_log_goes_with_it(small_case, monkeypatch):
    """A solver built for one call (cache=False) leaves no log file after
    it (the log was read: restoration counted); nor do cached ones once the
    cache is cleared."""
    import gc

    import belief_nlp as bn
    from belief_nlp.methods import nlp_build
    from belief_nlp.methods.ipopt import IPOPT
    sc, path = small_case
    read = []
    count = type(IPOPT).restoration

    def restoration(self, stats, log_path, offset):
        read.append(os.path.getsize(log_path) - offset)      # the solve's part of the log, when it is read
        return count(self, stats, log_path, offset)
    monkeypatch.setattr(type(IPOPT), "restoration", restoration)
    before = _logs()
    r = bn.smooth(sc, path, method="ipopt", K=7, cache=False)
    gc.collect()
    assert r.safe and len(read) == len(r.stats["attempts"]) and min(read) > 1000
    assert _logs() <= before
    bn.smooth(sc, path, method="ipopt", K=7)
    assert len(_logs() - before) == 2
    nlp_build.clear_cache()
    gc.collect()
    assert _logs() <= before


def test_a_cached_solver_with_a_long_log_is_built_anew(small_case, monkeypatch):
    import gc

    import belief_nlp as bn
    sc, path = small_case
    first = bn.smooth(sc, path, method="ipopt", K=9)
    again = bn.smooth(sc, path, method="ipopt", K=9)
    assert again.stats["build"] == "memory"
    logs = _logs()
    monkeypatch.setattr(solver_logs, "LOG_LIMIT", 1)
    renewed = bn.smooth(sc, path, method="ipopt", K=9)
    gc.collect()
    assert renewed.stats["build"] != "memory"
    assert renewed.cost == first.cost and renewed.nit == first.nit     # the same solve, a new log
    assert not logs & _logs()                                           # the long logs are gone


def test_a_forked_child_leaves_the_parents_logs(small_case):
    """A forked worker that drops an inherited solver must not remove the
    log its parent's solver still writes to."""
    import gc

    import belief_nlp as bn
    from belief_nlp.methods import nlp_build
    sc, path = small_case
    bn.smooth(sc, path, method="ipopt", K=11)
    logs = _logs()
    pid = os.fork()
    if pid == 0:                                  # the child: drop every inherited solver
        nlp_build.clear_cache()
        gc.collect()
        os._exit(0)
    os.waitpid(pid, 0)
    assert logs <= _logs()
