"""The watchdog around solves that cannot call back (belief_nlp.methods.nlp_guarded):
fatrop runs in a forked child that is ended on the run's deadline or when it
stops printing iteration lines (one K = 40 solve hung inside an iteration)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import belief_nlp as bn
from belief_nlp.methods import fatrop, nlp_guarded
from belief_nlp.methods.nlp_guarded import can_fork, guarded_call

pytestmark = pytest.mark.skipif(not can_fork(), reason="no os.fork on this platform: solves run in the process")


class _Fake:
    """A stand-in solver for the child: prints iteration lines, then returns, hangs or raises."""

    def __init__(self, lines: int, then: str):
        self.lines, self.then = lines, then

    def __call__(self, **args):
        for i in range(self.lines):
            os.write(1, f"{i:5d}  1.0e+00  2.0e-01\n".encode())
        if self.then == "hang":
            while True:             # silent, like fatrop inside its KKT reduction
                time.sleep(0.05)
        if self.then == "raise":
            raise RuntimeError("the plug-in failed: NaN in the KKT system")
        return {"x": np.asarray(args["x0"]) * 2.0, "f": np.array([[3.0]])}

    def stats(self):
        return {"iter_count": self.lines, "success": self.then == "return"}


def _stats(solver):
    return solver.stats()


def test_an_answer_comes_back_with_the_childs_stats_and_cpu():
    sol, st, ended = guarded_call(_Fake(3, "return"), {"x0": np.arange(4.0)}, _stats, deadline=None)
    assert ended is None and st["iter_count"] == 3 and st["success"]
    np.testing.assert_array_equal(sol["x"], 2.0 * np.arange(4.0))
    assert st["child_cpu_time"] >= 0.0


def test_a_silent_child_is_ended_as_stalled_with_its_last_iteration():
    t = time.perf_counter()
    sol, st, ended = guarded_call(_Fake(7, "hang"), {"x0": np.zeros(2)}, _stats, deadline=None, stall=0.5)
    assert ended == "stalled" and sol is None
    assert st["iter_count"] == 6                         # the last line printed: "    6 ..."
    assert time.perf_counter() - t < 60                  # it returned (no hang), whatever the CPU


class _Paced(_Fake):
    """Prints ``lines`` lines ``gap`` s apart, is silent for ``pause`` s, then answers."""

    def __init__(self, lines: int, gap: float, pause: float):
        super().__init__(lines, "return")
        self.gap, self.pause = gap, pause

    def __call__(self, **args):
        for i in range(self.lines):
            os.write(1, f"{i:5d}  1.0\n".encode())
            time.sleep(self.gap)
        time.sleep(self.pause)
        return {"x": np.zeros(1), "f": np.array([[0.0]])}


def test_a_silence_long_against_the_solves_own_cadence_is_a_stall():
    """Lines 10 ms apart, then 8 s of silence: a stall, although the cap
    (600 s here, STALL_SECONDS by default) is far off -- the limit follows the
    cadence (STALL_FACTOR x the longest wait, at least STALL_FLOOR = 2 s)."""
    assert nlp_guarded.STALL_FLOOR < 8.0 < nlp_guarded.STALL_SECONDS
    sol, st, ended = guarded_call(_Paced(20, 0.01, 8.0), {}, _stats, deadline=None, stall=600)
    assert ended == "stalled" and sol is None and st["iter_count"] == 19


def test_a_slow_but_steady_child_is_not_a_stall():
    """Lines 0.6 s apart (60x the fast child's) from the start: each wait is
    within the floor, then within 100x the longest so far; it answers."""
    sol, st, ended = guarded_call(_Paced(6, 0.6, 0.0), {}, _stats, deadline=None, stall=600)
    assert ended is None and sol is not None


def test_the_deadline_ends_a_child_that_is_still_printing():
    class Chatty(_Fake):
        def __call__(self, **args):
            i = 0
            while True:
                os.write(1, f"{i:5d}  1.0\n".encode())
                i += 1
                time.sleep(0.01)

    sol, st, ended = guarded_call(Chatty(0, ""), {}, _stats, deadline=time.perf_counter() + 0.3, stall=60)
    assert ended == "time_limit" and sol is None and st["iter_count"] > 0


def test_an_exception_in_the_parent_ends_the_child():
    """Ctrl-C while a child hangs: the child is killed and reaped (without
    the kill, the wait for it would never return)."""
    import signal

    class Interrupt(Exception):
        pass

    def raise_(*_):
        raise Interrupt

    old = signal.signal(signal.SIGALRM, raise_)
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.3)
        with pytest.raises(Interrupt):
            guarded_call(_Fake(1, "hang"), {}, _stats, deadline=None, stall=600)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def test_the_solvers_runtime_error_is_raised_here():
    with pytest.raises(RuntimeError, match="NaN in the KKT system"):
        guarded_call(_Fake(1, "raise"), {}, _stats, deadline=None)


@pytest.mark.skipif(not fatrop.available(), reason="this CasADi build has no fatrop plug-in")
def test_fatrop_in_the_child_gives_the_in_process_answer_bit_for_bit(small_start, monkeypatch):
    sc, ws = small_start
    forked = bn.smooth(sc, ws, method="fatrop", alpha=1.0)
    assert forked.stats["attempts"][0]["cpu_time"] > 0          # the child's CPU counted
    monkeypatch.setattr(fatrop, "can_fork", lambda: False)
    inside = bn.smooth(sc, ws, method="fatrop", alpha=1.0)
    assert forked.status == inside.status and forked.nit == inside.nit
    assert forked.cost == inside.cost
    np.testing.assert_array_equal(forked.path.x, inside.path.x)


@pytest.mark.skipif(not fatrop.available(), reason="this CasADi build has no fatrop plug-in")
def test_a_fatrop_solve_ended_from_outside_is_an_honest_time_limit(small_start, monkeypatch):
    """The real fatrop child, its deadline already passed when it starts:
    ended at once, the attempt and the status say so, the answer is the
    start (safe, never above it)."""
    real = fatrop.FatropBackend.solve
    monkeypatch.setattr(fatrop.FatropBackend, "solve",
                        lambda self, solver, args, deadline: real(self, solver, args, time.perf_counter()))
    sc, ws = small_start
    res = bn.smooth(sc, ws, method="fatrop", alpha=1.0)
    assert res.stats["attempts"][0]["return_status"] == "Maximum_WallTime_Exceeded"
    assert res.status == "time_limit" and not res.success
    assert res.nit == res.stats["iter_count"]       # what the child did, though no point came back
    assert res.safe and res.cost <= res.initial_cost and bn.verify(sc, res.path).safe


@pytest.mark.skipif(not fatrop.available(), reason="this CasADi build has no fatrop plug-in")
def test_fatrops_lines_are_shown_only_when_asked(small_start, capsys):
    sc, ws = small_start
    bn.smooth(sc, ws, method="fatrop", alpha=1.0, max_iter=4)
    assert "objective" not in capsys.readouterr().out
    bn.smooth(sc, ws, method="fatrop", alpha=1.0, max_iter=4, solver_options={"print_level": 5})
    assert "objective" in capsys.readouterr().out


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_the_child_dies_with_its_parent(tmp_path):
    """A study's case timeout kills the worker: a hung solve must not live on."""
    pidfile = tmp_path / "child.pid"
    script = (
        "import os, time\n"
        "from belief_nlp.methods.nlp_guarded import guarded_call\n"
        "class Hang:\n"
        "    def __call__(self, **a):\n"
        f"        open({str(pidfile)!r}, 'w').write(str(os.getpid()))\n"
        "        while True:\n"
        "            time.sleep(0.05)\n"
        "guarded_call(Hang(), {}, lambda s: {}, deadline=None, stall=600)\n")
    parent = subprocess.Popen([sys.executable, "-c", script])
    try:
        t = time.perf_counter()
        while not (pidfile.exists() and pidfile.read_text()) and time.perf_counter() - t < 120:
            time.sleep(0.05)
        child = int(pidfile.read_text())
    finally:
        parent.kill()
        parent.wait()

    def alive() -> bool:
        try:
            state = Path(f"/proc/{child}/status").read_text()
        except OSError:
            return False
        return "\nState:\tZ" not in state              # a zombie is dead, waiting to be reaped

    t = time.perf_counter()
    while alive() and time.perf_counter() - t < 30:
        time.sleep(0.05)
    assert not alive()
