"""A per-process folder for solvers' log files, and the sweep of folders
whose process died without removing its own.

A process removes its folder at exit (``atexit``), but a process ended by a
signal or by ``os._exit`` never runs that: a Jupyter kernel shut down by its
client, a study worker killed at its case timeout, a Dask worker its nanny
restarts. Each left a folder in the temporary directory (464 of them after
one day of test and notebook runs here, three per notebook check). So the
folder's name carries its process id, and the first folder a process makes
sweeps those whose process no longer exists.
"""

from __future__ import annotations

import atexit
import os
import re
import shutil
import tempfile

__all__ = ["log_dir", "sweep_stale"]

_DIRS: dict[str, str] = {}


def log_dir(tag: str) -> str:
    """This process's folder ``belief_nlp_<tag>_<pid>_*`` in the temporary
    directory, made on first use (after sweeping stale ones) and removed at exit."""
    found = _DIRS.get(tag)
    # a forked child inherits the parent's folder, which the parent removes
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
