"""Former home of ``smooth``; kept so old imports keep working (see :mod:`belief_nlp.smoother`)."""

from .smoother import smooth

__all__ = ["smooth", "METHODS"]


def __getattr__(name: str):
    if name == "METHODS":          # the registry's names at the time of asking
        from .smoother import available_methods

        return tuple(available_methods())
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
