"""numba's on-disk cache of the compiled attempt: whether it is there, and
dropping it when a source changed (numba keys a function's cache on its own
file only, not on the files of the functions it calls)."""

from __future__ import annotations

import hashlib
from pathlib import Path

__all__ = ["cache_is_warm", "drop_stale_cache"]

_HERE = Path(__file__).resolve().parent
# the sources of the compiled functions (refine_scalar's layers are compiled from its Python source)
# and of the constants compiled into them (metrics.LOSSLESS_RTOL, iteration._REL_EPS)
_SOURCES = ([_HERE / f for f in ("linalg.py", "collide.py", "attempt.py")]
            + [_HERE.parent / f for f in ("refine_scalar.py", "metrics.py", "iteration.py")])


def drop_stale_cache() -> None:
    """Remove numba's cached machine code of the compiled attempt when one of
    its sources changed since the cache was written (an edited callee would
    otherwise run stale from the caller's cache). Best effort: a read-only
    install keeps its cache where numba puts it (its files change only with
    a new version)."""
    stamp = hashlib.sha1(b"".join(p.read_bytes() for p in _SOURCES)).hexdigest()
    marker = _HERE / "__pycache__" / "sources.sha1"
    try:
        if marker.exists() and marker.read_text() == stamp:
            return
        for folder, prefix in ((_HERE, ""), (_HERE.parent, "refine_scalar.")):
            for f in (folder / "__pycache__").glob(prefix + "*.nb[ic]"):
                f.unlink()
        marker.parent.mkdir(exist_ok=True)
        marker.write_text(stamp)
    except OSError:
        pass


def cache_is_warm() -> bool:
    """Whether numba's on-disk cache of the attempt is there: the first plan
    of a machine compiles for about 12 s (docs/planner.md, "Fourth round"),
    later ones load it. Asks numba where it keeps the attempt's cache (next
    to the source, or a user-wide folder when the package is read-only, or
    ``NUMBA_CACHE_DIR``); imports numba (about 0.2 s), so call it only when
    numba is about to run."""
    drop_stale_cache()                  # before numba reads the cache
    from .attempt import attempt

    try:
        return Path(attempt._cache._cache_file._index_path).exists()     # numba's own locator (private API)
    except AttributeError:                                                # another numba: look next to the source
        return any((_HERE / "__pycache__").glob("attempt.attempt-*.nbi"))
