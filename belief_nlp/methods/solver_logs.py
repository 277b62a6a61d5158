"""A per-process folder for solvers' log files, and the sweep of folders
whose process died without removing its own.

A process removes its folder at exit (``atexit``), but a process ended by a
signal or by ``os._exit`` never runs that: a Jupyter kernel shut down by its
client, a study worker killed at its case timeout, a Dask worker its nanny
restarts. Each left a folder in the temporary directory (464 of them after
one day of test and notebook runs here, three per notebook check). So the
folder's name carries its process id, and the first folder a process makes
sweeps those whose process no longer exists.

Inside a process, a log file lives as long as the solver writing it (the
recorder that holds its path: :func:`tie`), and a cached solver whose log
has grown past :data:`LOG_LIMIT` is built anew (:func:`full`): a study of
thousands of cases in one worker otherwise kept a file per solver it had
built, and IPOPT appends ~10 KB per K = 20 smooth to a solver's log.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import re
import shutil
import tempfile
import weakref

__all__ = ["log_dir", "sweep_stale", "tie", "full", "LOG_LIMIT"]

#: bytes of log after which a cached solver is built anew (with a new log):
#: about 1,600 smooths at K = 20; a new IPOPT solver around the graph's
#: derivative functions costs ~0.06 s a stage (docs/numerics.md)
LOG_LIMIT = 16 * 2**20

_DIRS: dict[str, str] = {}


def log_dir(tag: str) -> str:
    """This process's folder ``belief_nlp_<tag>_<pid>_*`` in the temporary
    directory, made on first use (after sweeping stale ones) and removed at exit."""
    found = _DIRS.get(tag)
    # (a forked child shares its parent's folder, and makes its own once that is gone)
    if found is None or not os.path.isdir(found):
        sweep_stale(tag)
        found = tempfile.mkdtemp(prefix=f"belief_nlp_{tag}_{os.getpid()}_")
        _DIRS[tag] = found
        atexit.register(shutil.rmtree, found, True)
    return found


def sweep_stale(tag: str, root: str | None = None) -> list[str]:
    """Remove this user's ``belief_nlp_<tag>_<pid>_*`` folders in ``root``
    (default: the temporary directory) whose process is gone; the removed paths.
    Only where a process can be probed without harm (POSIX: signal 0)."""
    if os.name != "posix":
        return []
    root = root or tempfile.gettempdir()
    pattern = re.compile(rf"belief_nlp_{re.escape(tag)}_(\d+)_")
    removed = []
    try:
        entries = list(os.scandir(root))
    except OSError:
        return []
    for entry in entries:
        match = pattern.match(entry.name)
        try:
            if not match or not entry.is_dir(follow_symlinks=False) \
                    or entry.stat(follow_symlinks=False).st_uid != os.getuid() or _alive(int(match.group(1))):
                continue
        except OSError:
            continue
        shutil.rmtree(entry.path, ignore_errors=True)
        removed.append(entry.path)
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True      # another user's process (or no such pid number): leave it
    return True


def tie(owner: object, path: str | None) -> None:
    """Remove the log file ``path`` when ``owner`` (its solver's recorder) is
    collected: a solver dropped from the cache, or built for one call. Only
    in the process that made it: a forked child (a study worker) that drops
    an inherited solver leaves the parent's log alone."""
    if path:
        weakref.finalize(owner, _remove, path, os.getpid())


def full(path: str | None) -> bool:
    """Whether the log file ``path`` has grown past :data:`LOG_LIMIT`."""
    try:
        return bool(path) and os.path.getsize(path) > LOG_LIMIT
    except OSError:
        return False


def _remove(path: str, pid: int) -> None:
    if os.getpid() == pid:
        with contextlib.suppress(OSError):
            os.remove(path)
