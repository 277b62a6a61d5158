"""Compiled problems kept in memory and, when asked, on disk.

Building a (scenario, K)'s solver forms costs about a second in a process's
first call (docs/numerics.md, "Construction cost"): the CVXPY problem of the
CCP step, the active-set step's Clarabel data, IPOPT's derivative functions.
The memory cache keeps the last few; the disk cache (off by default:
:func:`set_disk_cache`, or the environment variable ``BELIEF_NLP_CACHE_DIR``)
keeps them across processes -- notebook kernels, study workers, CLI runs:

* only in the user's own cache directory (``$XDG_CACHE_HOME/belief_nlp`` or
  ``~/.cache/belief_nlp``) or a folder the user names;
* an entry's name is a hash of everything that shapes the problem (the
  scaled scenario data, the margin, the solver, the versions of belief_nlp,
  cvxpy and casadi, a hash of this model package's source files), so a
  stale entry is never found, not even from a development checkout;
* every entry is signed with an HMAC key kept in that folder (mode 0600);
  an entry that is unreadable, unsigned, signed with another key, not owned by
  the user or writable by others is ignored and rebuilt -- a pickle from
  elsewhere is never loaded;
* writes are atomic (a temporary file renamed into place); entries are
  compressed (zlib level 1: IPOPT's Hessian function 6.7 -> 0.85 MB at K = 20);
* the folder is kept under a size cap (512 MB by default): after a write,
  the least recently used entries (a load touches its file) are deleted.
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
import zlib
from collections import OrderedDict
from pathlib import Path

import numpy as np

from .data import ProblemData

__all__ = ["problem_key", "MemoryCache", "DiskCache", "default_cache_dir", "MEMORY", "set_disk_cache",
           "disk_cache", "ENV_DIR", "ENV_COMPILE", "compile_enabled"]

log = logging.getLogger("belief_nlp.cache")

# bump when the model's structure changes in a way the versions do not show
# (5: alpha became a parameter of every form and left the key; 6: entries compressed;
# 7: the start belief became a parameter of every form and left the key;
# 8: the CCP step's start relief became one parameter per transition)
MODEL_REVISION = 8

#: environment variable that switches the disk cache on for a process: a
#: folder, or "1" for the user's cache folder (:func:`default_cache_dir`)
ENV_DIR = "BELIEF_NLP_CACHE_DIR"
#: environment variable that also compiles IPOPT's derivative functions into
#: a library in the disk cache ("1"; methods/nlp_compiled.py)
ENV_COMPILE = "BELIEF_NLP_CACHE_COMPILE"
#: default size cap of a disk cache folder
MAX_BYTES = 512 * 2**20


def problem_key(D: ProblemData, chi2_margin: float, solver: str, proximal: float = 0.0) -> str:
    """Hash of everything that shapes the compiled problem. alpha and the
    start belief (x0, P0) are not part of it: every form takes them as
    parameters (the NLP's ``p``, the CCP step's), so one compiled problem
    serves every alpha and every start of a (scenario, K): a re-plan from a
    new belief builds nothing."""
    import casadi

    from .._version import __version__

    h = hashlib.sha256()
    for part in (MODEL_REVISION, __version__, _source_digest(), _cvxpy_version(), casadi.__version__, solver,
                 repr(chi2_margin),
                 *((repr(proximal),) if proximal else ()),
                 D.sigma, D.chi2, D.chi2_target, D.budget, D.continuous, D.K, D.d, D.hazard_names):
        h.update(repr(part).encode())
    for arr in (D.W, D.A, D.b, D.face_mask, D.At, D.bt):
        a = np.ascontiguousarray(arr)
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:40]


@functools.lru_cache(maxsize=1)
def _source_digest() -> str:
    """Hash of the model package's own source files: what the compiled forms
    are generated from. A development checkout whose model code changed
    without a version bump then never finds the entries of the old code
    (read once a process, ~1 ms)."""
    h = hashlib.sha256()
    for path in sorted(Path(__file__).resolve().parent.glob("*.py")):
        h.update(path.name.encode() + path.read_bytes())
    return h.hexdigest()[:16]


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
    """Signed, compressed pickles of compiled problems in one folder (see
    module doc). ``kind`` names an entry's type in its file name
    (``<key>.<kind>.pkl``)."""

    def __init__(self, directory: str | Path | None = None, max_bytes: int = MAX_BYTES):
        self.dir = Path(directory).expanduser() if directory is not None else default_cache_dir()
        self.max_bytes = int(max_bytes)

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

    def load(self, name: str, kind: str = "ccp"):
        """The entry, or None when missing, unreadable, foreign or tampered with."""
        path = self.dir / f"{name}.{kind}.pkl"
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
            value = pickle.loads(zlib.decompress(payload))  # noqa: S301 - signed by this user's own key (module doc)
            os.utime(path)              # recently used: the size cap evicts the others first
            return value
        except Exception as exc:  # an unreadable entry is rebuilt, never fatal
            log.warning("ignoring cache entry %s: %s", path.name, exc)
            return None

    def save(self, name: str, value, kind: str = "ccp") -> Path | None:
        """Write atomically, then keep the folder under its size cap; returns
        the path (None when caching is not possible)."""
        try:
            key = self._key(create=True)
            if key is None:
                return None
            payload = zlib.compress(pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL), 1)
            fd, tmp = tempfile.mkstemp(dir=self.dir, prefix=".tmp-", suffix=".pkl")
            with os.fdopen(fd, "wb") as f:
                f.write(hmac.new(key, payload, hashlib.sha256).digest() + payload)
            final = self.dir / f"{name}.{kind}.pkl"
            os.replace(tmp, final)
            self._evict(keep=final)
            return final
        except Exception as exc:
            log.warning("could not write the problem cache in %s: %s", self.dir, exc)
            return None

    def entries(self) -> list[Path]:
        """The folder's entries (every kind: signed pickles and compiled libraries)."""
        return [p for pattern in ("*.pkl", "*.so") for p in self.dir.glob(pattern) if not p.name.startswith(".")]

    def _sized(self) -> list[tuple[float, int, Path]]:
        """(mtime, bytes, path) of every entry, least recently used first (an
        entry removed meanwhile by another process is left out)."""
        out = []
        for p in self.entries():
            try:
                st = p.stat()
            except OSError:
                continue
            out.append((st.st_mtime, st.st_size, p))
        return sorted(out, key=lambda t: t[0])

    def summary(self) -> dict[str, tuple[int, int]]:
        """{kind: (entries, bytes)} of the folder."""
        out: dict[str, tuple[int, int]] = {}
        for _, size, p in self._sized():
            kind = p.name.split(".")[-2]          # <key>.<kind>.pkl
            n, total = out.get(kind, (0, 0))
            out[kind] = (n + 1, total + size)
        return out

    def clear(self) -> tuple[int, int]:
        """Delete every entry (the key stays); returns (entries, bytes) deleted."""
        return self._delete(self._sized(), limit=0)

    def _evict(self, keep: Path) -> None:
        """Delete the least recently used entries (file mtime: written or
        loaded) until the folder is within ``max_bytes``; never ``keep``."""
        sized = self._sized()
        self._delete([e for e in sized if e[2] != keep], limit=self.max_bytes, total=sum(e[1] for e in sized))

    @staticmethod
    def _delete(sized: list, limit: int, total: int | None = None) -> tuple[int, int]:
        """Delete ``sized``'s entries in order while ``total`` (default: their
        bytes) is above ``limit``; returns (entries, bytes) deleted."""
        total = sum(e[1] for e in sized) if total is None else total
        n = freed = 0
        for _, size, p in sized:
            if total - freed <= limit:
                break
            try:
                p.unlink()
                n, freed = n + 1, freed + size
            except OSError:
                pass
        return n, freed

_DISK: dict = {"set": False, "cache": None, "compile": False}


def _off(value: str) -> bool:
    return value.strip().lower() in ("", "0", "off", "false", "no")


def set_disk_cache(where: bool | str | Path | None = True, max_mb: float = MAX_BYTES / 2**20,
                   compile: bool = False) -> DiskCache | None:
    """Keep compiled problems on disk across processes, or stop doing so.

    What a process's first call builds (the NLP graph, IPOPT's derivative
    functions, the active-set step's Clarabel data, the CVXPY problem of the
    CCP step) is
    then loaded by later processes -- notebook kernels, study workers, CLI
    runs -- instead of built (measured: docs/numerics.md, "Construction cost").

    Parameters
    ----------
    where : bool, str, Path or None, optional
        True for the user's cache folder (``$XDG_CACHE_HOME/belief_nlp`` or
        ``~/.cache/belief_nlp``), a folder, or False / None to switch the disk
        cache off (the memory cache stays). Without a call, the environment
        variable ``BELIEF_NLP_CACHE_DIR`` decides (a folder, or "1" for the
        user's cache folder; unset, empty or "0": off).
    max_mb : float, optional
        Size cap of the folder in MB; the least recently used entries are
        deleted first.
    compile : bool, optional
        Also compile IPOPT's derivative functions with the system C compiler
        into a library in the folder, in a background process started by the
        call that first writes them (about 25 s of one core at K = 20, 4.5 min
        at K = 80); later processes load the library instead of the
        serialised functions (about 0.3 s less in their first call at K = 20)
        and evaluate it faster (calls about 15 % faster).
        Pays off for a few problem shapes solved in many processes (MPC,
        notebooks), not for a study over random maps. Without a C compiler
        it does nothing. Environment variable: ``BELIEF_NLP_CACHE_COMPILE``.

    Returns
    -------
    DiskCache or None
        The process's disk cache from now on (None when off). The setting
        is also written to ``BELIEF_NLP_CACHE_DIR``, so processes started
        afterwards -- a study's worker pool, a Dask ``LocalCluster`` -- share it
        (the size cap stays at their default).

    Raises
    ------
    ValidationError
        For a ``where`` or ``max_mb`` of the wrong kind.
    """
    from ..errors import ValidationError

    if not isinstance(max_mb, (int, float)) or isinstance(max_mb, bool) or not max_mb > 0:
        raise ValidationError("max_mb", f"must be a number of megabytes > 0, got {max_mb!r}")
    if not isinstance(compile, bool):
        raise ValidationError("compile", f"must be True or False, got {compile!r}")
    if compile and (where is None or where is False):
        raise ValidationError("compile", "compiles into the disk cache: it needs one (where=True or a folder)")
    if where is None or where is False:
        cache, env = None, "0"
    elif where is True:
        cache, env = DiskCache(None, int(max_mb * 2**20)), "1"
    elif isinstance(where, (str, Path)) and str(where).strip():
        cache = DiskCache(where, int(max_mb * 2**20))
        env = str(cache.dir.resolve())
    else:
        raise ValidationError("where", f"must be True, False, None or a folder, got {where!r}")
    _DISK.update(set=True, cache=cache, compile=compile)
    # processes started from now on (a study's worker pool, a Dask LocalCluster) read the variables
    os.environ[ENV_DIR] = env
    os.environ[ENV_COMPILE] = "1" if _DISK["compile"] else "0"
    return cache


def disk_cache() -> DiskCache | None:
    """The process's disk cache (None: off); see :func:`set_disk_cache`."""
    if not _DISK["set"]:
        value = os.environ.get(ENV_DIR, "").strip()
        cache = None if _off(value) else DiskCache(None if value == "1" else value)
        flag = os.environ.get(ENV_COMPILE, "")
        on = flag.strip().lower() in ("1", "on", "true", "yes")
        if not on and not _off(flag):
            log.warning("%s=%r is neither on (1, on, true, yes) nor off (0, off, false, no, empty): "
                        "not compiling", ENV_COMPILE, flag)
        _DISK.update(set=True, cache=cache, compile=cache is not None and on)
    return _DISK["cache"]


def compile_enabled() -> bool:
    """Whether the disk cache also compiles derivative functions (see
    :func:`set_disk_cache`)."""
    return disk_cache() is not None and _DISK["compile"]
