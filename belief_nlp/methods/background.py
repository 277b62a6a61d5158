"""Work run in a thread of its own beside a solve that releases the GIL.

IPOPT's solve (a CasADi ``nlpsol`` call) releases the GIL, and CasADi's
wheels are built with thread-safe symbolics (``CASADI_WITH_THREADSAFE_SYMBOLICS``),
so a symbolic build started just before a solve runs on another core while
the solve runs (docs/numerics.md, "The active-set step beside IPOPT's
solve"). A job is keyed; its starter takes the value back with :func:`take`
(waiting if needed) and :func:`settle` collects finished jobs nobody asked
for yet. Only the caller's thread touches this module's state: a job
computes and returns, nothing else.

Each job has a thread that ends with it, so no idle thread outlives the
work. Before a fork (:mod:`.nlp_guarded`) :func:`wait_all` lets every job
finish: a child forked while a job holds one of CasADi's locks could wait
on it forever.
"""

from __future__ import annotations

import os
import threading
from typing import Any, Callable

__all__ = ["start", "take", "settle", "wait_all", "running", "cpus"]


class _Job:
    """One call of ``fn`` in a new thread; its value or its exception."""

    def __init__(self, fn: Callable[[], Any]):
        self._fn = fn
        self.value: Any = None
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, name="belief_nlp-background")
        self.thread.start()

    def _run(self) -> None:
        try:
            self.value = self._fn()
        except BaseException as exc:        # handed to the caller's thread by take()
            self.error = exc
        finally:
            self._fn = None


_JOBS: dict[str, _Job] = {}


def cpus() -> int:
    """CPUs this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:              # not on macOS / Windows
        return os.cpu_count() or 1


def running(key: str) -> bool:
    """Whether a job of ``key`` was started and not taken yet."""
    return key in _JOBS


def start(key: str, fn: Callable[[], Any]) -> bool:
    """Run ``fn`` in a thread under ``key``; False (nothing started) when a
    job of that key is there already or one CPU is all this process may use."""
    if key in _JOBS or cpus() < 2:
        return False
    _JOBS[key] = _Job(fn)
    return True


def take(key: str) -> tuple[bool, Any]:
    """(True, value) of the job of ``key`` (waited for), or (False, None)
    when there is none or it raised: the caller then does the work itself,
    where an error that recurs is raised with its own traceback."""
    job = _JOBS.pop(key, None)
    if job is None:
        return False, None
    job.thread.join()
    return (job.error is None), job.value


def settle() -> list[tuple[str, Any]]:
    """(key, value) of every finished job that did not raise, taken."""
    done = [k for k, job in _JOBS.items() if not job.thread.is_alive()]
    out = []
    for key in done:
        ok, value = take(key)
        if ok:
            out.append((key, value))
    return out


def wait_all() -> None:
    """Let every running job finish (they stay to be taken)."""
    for job in list(_JOBS.values()):
        job.thread.join()
