"""One nlpsol call in a forked child under a watchdog, for plug-ins that
never call back (fatrop).

A plug-in without an iteration callback cannot be stopped from Python: the
time limit is checked between solves only, and a solve that hangs inside
one iteration hangs the caller. fatrop 1.1.8 does (paper-multi K = 40,
seed 1, alpha 0.1: inside its restoration phase's KKT reduction after
iteration 121, measured with py-spy; docs/numerics.md, "fatrop"). So the
solve runs in a forked copy of the process, which inherits the built
solver (nothing is rebuilt or pickled but the answer). The child's stdout
is a pipe, both the C-level one and Python's ``sys.stdout`` (CasADi hands
its plug-ins' output to the latter); the plug-in prints a line per
iteration, and each line is a heartbeat. The parent ends the child when
the run's deadline passes or no line came for too long, and reports which;
an exception in the parent (Ctrl-C) ends it too. "Too long" follows the
solve's own cadence: :data:`STALL_FACTOR` times the longest wait for a
line so far (the first one included), at least :data:`STALL_FLOOR` and at
most :data:`STALL_SECONDS` (docs/numerics.md, "fatrop": 86 answered solves
at K = 20 and 40, 2-D and 3-D, waited at most 0.022 s for a line; a hung
one waits forever).

Where ``os.fork`` does not exist (Windows) the call runs in the process, as
before, and only the plug-in's own iteration limit bounds it.
"""

from __future__ import annotations

import ctypes
import os
import pickle
import selectors
import signal
import sys
import time
import warnings
from typing import Any, Callable

import numpy as np

from . import background

__all__ = ["guarded_call", "can_fork", "STALL_SECONDS", "STALL_FLOOR", "STALL_FACTOR"]

#: a child that printed no line for this long is stuck inside an iteration
#: (fatrop's iterations take 2-50 ms at K = 20-80 here; the hang was silent):
#: the cap, and the limit before the first line
STALL_SECONDS = 20.0
#: once lines come, a wait STALL_FACTOR times the longest one so far is a stall,
#: but never one shorter than STALL_FLOOR: the limit scales with the solve's
#: own iteration time (a larger problem, a slower machine), not with a constant
STALL_FACTOR = 100.0
STALL_FLOOR = 2.0


def can_fork() -> bool:
    """Whether this platform can run a solve in a forked child."""
    return hasattr(os, "fork") and sys.platform != "win32"


def _libc() -> Any:
    """The C library (None where ctypes cannot load it)."""
    try:
        return ctypes.CDLL(None)
    except OSError:
        return None


def _line_buffered(libc: Any) -> None:
    """C stdout line-buffered: it is a pipe now, which C buffers by 4 KiB
    blocks, so the plug-in's lines would come as late, coarse heartbeats."""
    for symbol in ("stdout", "__stdoutp"):          # glibc / musl, BSD libc (macOS)
        try:
            stream = ctypes.c_void_p.in_dll(libc, symbol)
        except ValueError:
            continue
        libc.setvbuf(stream, None, 1, 0)              # _IOLBF (1 in glibc, musl and BSD libc)
        return


def _die_with(parent: int, libc: Any) -> None:
    """Linux: the child is killed when its parent dies (a study's case
    timeout kills the worker), or a hung solve would outlive it on a core."""
    if libc is not None and sys.platform.startswith("linux"):
        libc.prctl(1, signal.SIGKILL)                 # PR_SET_PDEATHSIG
    if os.getppid() != parent:                        # the parent died before that
        os._exit(1)


def _child(solver: Any, args: dict, stats: Callable[[Any], dict], w_log: int, w_res: int, parent: int) -> None:
    """The child's side: solve with fd 1 on the heartbeat pipe, send
    ("ok", solution, stats) or ("raised", message, stats), exit at once."""
    code = 0
    libc = _libc()
    try:
        _die_with(parent, libc)
        os.dup2(w_log, 1)
        if libc is not None:
            _line_buffered(libc)
        # CasADi hands its plug-ins' output to Python's sys.stdout, which may be
        # a notebook's or pytest's stream: in the child it is the pipe too
        sys.stdout = open(1, "w", buffering=1, closefd=False)
        try:
            sol = solver(**args)
            out: tuple = ("ok", {k: np.asarray(v) for k, v in sol.items()}, stats(solver))
        except RuntimeError as exc:
            out = ("raised", str(exc), stats(solver))
        data = memoryview(pickle.dumps(out, protocol=pickle.HIGHEST_PROTOCOL))
        while data:
            data = data[os.write(w_res, data):]
    except BaseException:       # nothing may escape into the parent's copy of the interpreter
        code = 1
    finally:
        if libc is not None:
            libc.fflush(None)     # os._exit does not flush C streams
        os._exit(code)


def _last_iteration(log: bytes) -> int:
    """The last iteration number in the plug-in's log lines ("  121r  1.8e+00 ...": 121), 0 if none."""
    for line in reversed(log.decode(errors="replace").splitlines()):
        head = line.split(maxsplit=1)[0].rstrip("r") if line.strip() else ""
        if head.isdigit():
            return int(head)
    return 0


def _watch(r_log: int, r_res: int, deadline: float | None, stall: float,
           echo: bool) -> tuple[bytes, bytes, str | None]:
    """Read the child's two pipes until both close: (the pickled answer, the
    log's last 4 KiB, None), or stop early with the reason ("time_limit",
    "stalled"). Each log chunk is a heartbeat; ``echo`` copies it to stdout.
    ``stall`` is the longest wait allowed; once heartbeats come, the wait
    allowed is STALL_FACTOR times the longest one so far, within
    [min(STALL_FLOOR, stall), stall] (module doc)."""
    chunks: list[bytes] = []
    tail = b""
    last = time.perf_counter()
    longest = None                                   # the longest wait for a heartbeat so far
    with selectors.DefaultSelector() as sel:
        sel.register(r_log, selectors.EVENT_READ, "log")
        sel.register(r_res, selectors.EVENT_READ, "result")
        while sel.get_map():
            now = time.perf_counter()
            if deadline is not None and now >= deadline:
                return b"", tail, "time_limit"
            limit = stall if longest is None else min(stall, max(STALL_FLOOR, STALL_FACTOR * longest))
            if now - last >= limit:
                return b"", tail, "stalled"
            wait = limit - (now - last) if deadline is None else min(limit - (now - last), deadline - now)
            for key, _ in sel.select(timeout=max(wait, 0.0)):
                data = os.read(key.fd, 1 << 16)
                if not data:
                    sel.unregister(key.fd)
                elif key.data == "result":
                    chunks.append(data)
                else:
                    beat = time.perf_counter()
                    longest = max(longest or 0.0, beat - last)
                    last = beat
                    tail = (tail + data)[-4096:]
                    if echo:
                        sys.stdout.write(data.decode(errors="replace"))
    return b"".join(chunks), tail, None


def guarded_call(solver: Any, args: dict, stats: Callable[[Any], dict], deadline: float | None,
                 echo: bool = False, stall: float = STALL_SECONDS) -> tuple[Any, dict, str | None]:
    """``solver(**args)`` in a forked child: (solution dict or None, the
    solver's stats with the child's CPU seconds as "child_cpu_time", None or
    why the child was ended: "time_limit" when ``deadline`` (a
    ``time.perf_counter`` value) passed, "stalled" after ``stall`` s without
    output). A RuntimeError of the solver is raised here with its message;
    ``echo`` copies the child's output to stdout."""
    r_log, w_log = os.pipe()
    r_res, w_res = os.pipe()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (AttributeError, ValueError, OSError):
            pass
    libc = _libc()
    if libc is not None:
        libc.fflush(None)         # or the child would write this process's pending C output again
    parent = os.getpid()
    background.wait_all()       # no thread of ours inside CasADi (holding its locks) as the child is made
    with warnings.catch_warnings():
        # Python >= 3.12 warns on fork in a threaded process; the child runs the solver only
        warnings.simplefilter("ignore", DeprecationWarning)
        pid = os.fork()
    if pid == 0:                                                    # pragma: no cover (the child)
        os.close(r_log)
        os.close(r_res)
        _child(solver, args, stats, w_log, w_res, parent)
    os.close(w_log)
    os.close(w_res)
    answered = False
    try:
        result, tail, stop = _watch(r_log, r_res, deadline, stall, echo)
        answered = stop is None
    finally:
        if not answered:        # stopped, or an exception here (KeyboardInterrupt): the child must not live on
            os.kill(pid, signal.SIGKILL)
        os.close(r_log)
        os.close(r_res)
        usage = os.wait4(pid, 0)[2]
    # the child's CPU seconds, which time.process_time() of this process does not see
    cpu = {"child_cpu_time": usage.ru_utime + usage.ru_stime}
    if stop is not None:
        return None, {"iter_count": _last_iteration(tail), "watchdog": f"{stop}: ended from outside", **cpu}, stop
    try:
        kind, payload, st = pickle.loads(result)
    except Exception as exc:   # the child died before it could answer
        raise RuntimeError(f"the solver's process ended without an answer ({type(exc).__name__})") from None
    if kind == "raised":
        raise RuntimeError(payload)
    return payload, {**st, **cpu}, None
