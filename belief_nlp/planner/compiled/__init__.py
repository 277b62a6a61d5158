"""The compiled (numba) attempt of IG-RRT* for 2-D scenarios: ``PlannerOptions.backend``.

``"numpy"`` runs :meth:`..iteration.IterationMixin._iterate`, the reference;
``"numba"`` runs :class:`.driver.CompiledAttempt`: one compiled call per
attempt for nearest, steering, shrinking, edge costs and the collision
decisions (numba is the optional extra ``belief-nlp[fast]``); ``"auto"``
takes numba when it is installed and the configuration is supported.
Compiled functions are cached on disk (``cache=True``), so the compilation
is paid once per machine and source version, not per process. numba's cache
of a function is keyed on its own file only, not on the files of the
functions it calls; :func:`.cache.drop_stale_cache` (run when the driver is
imported) removes the cached machine code when any source changed.
"""

from __future__ import annotations

import functools
import importlib.util
import logging

from ...errors import ValidationError
from .cache import cache_is_warm, drop_stale_cache

__all__ = ["installed", "available", "unsupported", "resolve_backend", "drop_stale_cache", "cache_is_warm",
           "cold_compile_note"]

log = logging.getLogger("belief_nlp.planner")
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
