"""Jobs in a thread beside a solve (methods/background.py), and the fork of
a guarded solve (methods/nlp_guarded.py) waiting for them."""

from __future__ import annotations

import threading
import time

import pytest

from belief_nlp.methods import background, nlp_guarded

pytestmark = pytest.mark.skipif(background.cpus() < 2, reason="jobs start only with a second CPU")


@pytest.fixture(autouse=True)
def no_jobs():
    background.wait_all()
    background.settle()
    yield
    background.wait_all()
    background.settle()


def test_a_job_runs_in_its_own_thread_and_is_taken_once():
    seen = []
    assert background.start("a", lambda: seen.append(threading.current_thread().name) or 42)
    assert not background.start("a", lambda: 0)                  # the key is taken
    assert background.running("a")
    assert background.take("a") == (True, 42)
    assert seen == ["belief_nlp-background"]
    assert not background.running("a") and background.take("a") == (False, None)


def test_a_job_that_raises_leaves_the_work_to_the_caller():
    def fails():
        raise ValueError("no")

    assert background.start("b", fails)
    assert background.take("b") == (False, None)


def test_settle_takes_finished_jobs_only():
    gate = threading.Event()
    background.start("done", lambda: "x")
    background.start("waiting", lambda: gate.wait(5.0) and "y")
    background._JOBS["done"].thread.join()
    assert background.settle() == [("done", "x")]
    assert background.running("waiting")
    gate.set()
    background.wait_all()
    assert not background._JOBS["waiting"].thread.is_alive()      # finished, still there to be taken
    assert background.settle() == [("waiting", "y")]


def test_the_fork_of_a_guarded_solve_waits_for_running_jobs(monkeypatch):
    finished = threading.Event()

    def slow():
        time.sleep(0.3)
        finished.set()

    background.start("slow", slow)

    def fork():
        raise OSError("fork refused here" + (" after the job" if finished.is_set() else " during the job"))

    monkeypatch.setattr(nlp_guarded.os, "fork", fork)
    with pytest.raises(OSError, match="after the job"):
        nlp_guarded.guarded_call(None, {}, lambda s: {}, None)
