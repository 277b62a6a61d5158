"""The compiled (numba) attempt of IG-RRT* for 2-D scenarios: ``PlannerOptions.backend``.

``"numpy"`` runs :meth:`..iteration.IterationMixin._iterate`, the reference;
``"numba"`` runs :class:`.driver.CompiledAttempt`: one compiled call per
attempt for nearest, steering, shrinking, edge costs and the collision
decisions (numba is the optional extra ``belief-nlp[fast]``); ``"auto"``
takes numba when it is installed and the configuration is supported.
Compiled functions are cached on disk (``cache=True``), so the compilation
is paid once per machine and source version, not per process. numba's cache
of a function is keyed on its own file only, not on the files of the
functions it calls; :func:`drop_stale_cache` (run when the driver is
imported) removes the cached machine code when any source changed.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import logging
from pathlib import Path

from ...errors import ValidationError

__all__ = ["installed", "available", "unsupported", "resolve_backend", "drop_stale_cache", "cache_is_warm", "cold_compile_note"]

log = logging.getLogger("belief_nlp.planner")
_HERE = Path(__file__).resolve().parent
# the sources of the compiled functions (refine_scalar's layers are compiled from its Python source)
# and of the constants compiled into them (metrics.LOSSLESS_RTOL, iteration._REL_EPS)
_SOURCES = ([_HERE / f for f in ("linalg.py", "collide.py", "attempt.py")]
            + [_HERE.parent / f for f in ("refine_scalar.py", "metrics.py", "iteration.py")])

BACKENDS = ("auto", "numpy", "numba")


def installed() -> bool:
    """Whether numba is installed (without importing it)."""
    return importlib.util.find_spec("numba") is not None


@functools.lru_cache(maxsize=1)
def available() -> bool:
    """Whether numba is installed *and* imports (once per process, about
    0.2 s): an installed numba that does not import -- typically a NumPy newer
    than the numba release supports -- leaves ``"auto"`` on numpy, with one
    warning, instead of failing every plan."""
    if not installed():
        return False
    try:
        import numba  # noqa: F401
    except Exception as exc:            # ImportError, or numba's own version checks
        log.warning("numba is installed but does not import (%s); IG-RRT* plans with its numpy backend",
                    str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
        return False
    return True


def unsupported(dim: int, metric: str) -> str | None:
    """Why the compiled attempt cannot serve this configuration, or None."""
    if dim != 2:
        return f"it serves 2-D scenarios, not {dim}-D"
    if metric not in ("entropy", "hellinger"):
        return f"it serves the entropy and hellinger metrics, not {metric!r}"
    return None


def resolve_backend(backend: str, dim: int, metric: str) -> str:
    """The backend a planner runs: ``"numpy"`` or ``"numba"``.

    Raises
    ------
    ValidationError
        ``backend="numba"`` without numba installed (or with one that does
        not import), or for a configuration the compiled attempt does not
        serve.
    """
    if backend == "numpy":
        return "numpy"
    why = unsupported(dim, metric)
    if backend == "auto":
        return "numba" if why is None and available() else "numpy"
    if not available():
        if installed():
            raise ValidationError("backend", "'numba': numba is installed but does not import here (its "
                                             "warning says why); use backend='numpy' or 'auto'")
        raise ValidationError("backend", "'numba' needs the numba package: pip install 'belief-nlp[fast]' "
                                         "(or use backend='numpy')")
    if why is not None:
        raise ValidationError("backend", f"'numba' is not available here: {why} (use 'auto' or 'numpy')")
    return "numba"


def cache_is_warm() -> bool:
    """Whether numba's on-disk cache of the attempt is there: the first plan
    of a machine compiles for about 12 s (docs/planner.md, "Fourth round"),
    later ones load it. Asks numba where it keeps the attempt's cache (next
    to the source, or a user-wide folder when the package is read-only, or
    ``NUMBA_CACHE_DIR``); imports numba (about 0.2 s), so call it only when
    numba is about to run."""
    from . import driver  # noqa: F401 -- drops a stale cache before numba reads it
    from .attempt import attempt

    try:
        return Path(attempt._cache._cache_file._index_path).exists()     # numba's own locator (private API)
    except AttributeError:                                                # another numba: look next to the source
        return any((_HERE / "__pycache__").glob("attempt.attempt-*.nbi"))


COLD_NOTE = ("IG-RRT*: compiling the numba attempt, about 12 s once per machine "
             "(backend='numpy' plans without it)")


def cold_compile_note(backend: str, dim: int, metric: str) -> str | None:
    """:data:`COLD_NOTE` when a plan with these settings will compile the
    numba attempt first (numba runs and its cache is cold), else None."""
    try:
        runs_numba = resolve_backend(backend, dim, metric) == "numba"
    except ValidationError:
        return None                         # the planner itself reports the bad option
    return COLD_NOTE if runs_numba and not cache_is_warm() else None


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
