"""Compiled CCP problems kept in memory and, when asked, on disk.

Compiling the CVXPY problem of a (scenario, K) costs about a second
(docs/numerics.md); re-solving it costs milliseconds more than the solver.
The memory cache keeps the last few; the disk cache (off by default) keeps
them across processes:

* only in the user's own cache directory (``$XDG_CACHE_HOME/belief_nlp`` or
  ``~/.cache/belief_nlp``) or a folder the user names;
* an entry's name is a hash of everything that shapes the problem (the
  scaled scenario data, the margin, the solver, the versions of belief_nlp,
  cvxpy and casadi), so a stale entry is never found;
* every entry is signed with an HMAC key kept in that folder (mode 0600);
  an entry that is unreadable, unsigned, signed with another key, not owned by
  the user or writable by others is ignored and rebuilt -- a pickle from
  elsewhere is never loaded;
* writes are atomic (a temporary file renamed into place).
"""

from __future__ import annotations

import functools
import hashlib
import hmac
import logging
import os
import pickle
import secrets
import stat
import tempfile
from collections import OrderedDict
from pathlib import Path

import numpy as np

from .data import ProblemData

__all__ = ["problem_key", "MemoryCache", "DiskCache", "default_cache_dir", "MEMORY"]

log = logging.getLogger("belief_nlp.cache")

# bump when the model's structure changes in a way the versions do not show
# (5: alpha became a parameter of every form and left the key)
MODEL_REVISION = 5


def problem_key(D: ProblemData, chi2_margin: float, solver: str, proximal: float = 0.0) -> str:
    """Hash of everything that shapes the compiled problem. alpha is not part
    of it: every form takes alpha as a parameter (the NLP's ``p``, the CCP
    step's last parameter), so one compiled problem serves every alpha."""
    import casadi

    from .._version import __version__

    h = hashlib.sha256()
    for part in (MODEL_REVISION, __version__, _cvxpy_version(), casadi.__version__, solver, repr(chi2_margin),
                 *((repr(proximal),) if proximal else ()),
                 D.sigma, D.chi2, D.chi2_target, D.budget, D.continuous, D.K, D.d, D.hazard_names):
        h.update(repr(part).encode())
    for arr in (D.x0, D.P0, D.W, D.A, D.b, D.face_mask, D.At, D.bt):
        a = np.ascontiguousarray(arr)
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:40]


@functools.lru_cache(maxsize=1)
def _cvxpy_version() -> str:
    """cvxpy's version without importing it (the import costs ~0.4 s CPU, which
    the NLP methods' first call would pay for a key only); read once (the
    package metadata lookup took ~2.5 ms, three times per call)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("cvxpy")
    except PackageNotFoundError:
        return "none"


class MemoryCache:
    """Least-recently-used compiled problems of this process."""

    def __init__(self, size: int = 6):
        self.size = size
        self._d: OrderedDict = OrderedDict()

    def get(self, key: str):
        if key in self._d:
            self._d.move_to_end(key)
            return self._d[key]
        return None

    def put(self, key: str, value) -> None:
        self._d[key] = value
        self._d.move_to_end(key)
        while len(self._d) > self.size:
            self._d.popitem(last=False)

    def clear(self) -> None:
        self._d.clear()


MEMORY = MemoryCache()


def default_cache_dir() -> Path:
    """The user's own cache folder for belief_nlp."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "belief_nlp"


def _private(path: Path) -> bool:
    """Owned by this user and not writable by group or others."""
    try:
        st = path.stat()
    except OSError:
        return False
    uid = os.getuid() if hasattr(os, "getuid") else st.st_uid
    return st.st_uid == uid and not st.st_mode & (stat.S_IWGRP | stat.S_IWOTH)


class DiskCache:
    """Signed pickles of compiled problems in one folder (see module doc)."""

    suffix = ".ccp.pkl"

    def __init__(self, directory: str | Path | None = None):
        self.dir = Path(directory) if directory is not None else default_cache_dir()

    def _key(self, create: bool) -> bytes | None:
        kf = self.dir / "hmac.key"
        if kf.exists():
            if not _private(kf) or not _private(self.dir):
                log.warning("ignoring the cache in %s: its key or folder is not private to this user", self.dir)
                return None
            data = kf.read_bytes()
            return data if len(data) == 32 else None
        if not create:
            return None
        self.dir.mkdir(parents=True, exist_ok=True, mode=0o700)
        if not _private(self.dir):
            log.warning("not caching in %s: the folder is writable by others", self.dir)
            return None
        key = secrets.token_bytes(32)
        fd = os.open(kf, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(key)
        return key

    def load(self, name: str):
        """The entry, or None when missing, unreadable, foreign or tampered with."""
        path = self.dir / (name + self.suffix)
        try:
            if not path.exists():
                return None
            key = self._key(create=False)
            if key is None or not _private(path):
                return None
            blob = path.read_bytes()
            sig, payload = blob[:32], blob[32:]
            if not hmac.compare_digest(sig, hmac.new(key, payload, hashlib.sha256).digest()):
                log.warning("ignoring cache entry %s: bad signature", path.name)
                return None
            return pickle.loads(payload)  # noqa: S301 - signed by this user's own key (module doc)
        except Exception as exc:  # an unreadable entry is rebuilt, never fatal
            log.warning("ignoring cache entry %s: %s", path.name, exc)
            return None

    def save(self, name: str, value) -> Path | None:
        """Write atomically; returns the path (None when caching is not possible)."""
        try:
            key = self._key(create=True)
            if key is None:
                return None
            payload = pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL)
            fd, tmp = tempfile.mkstemp(dir=self.dir, prefix=".tmp-", suffix=self.suffix)
            with os.fdopen(fd, "wb") as f:
                f.write(hmac.new(key, payload, hashlib.sha256).digest() + payload)
            final = self.dir / (name + self.suffix)
            os.replace(tmp, final)
            return final
        except Exception as exc:
            log.warning("could not write the problem cache in %s: %s", self.dir, exc)
            return None
