"""Former home of ``smooth``; kept so old imports keep working (see :mod:`belief_nlp.smoother`)."""

from .smoother import available_methods, smooth

__all__ = ["smooth", "METHODS"]

METHODS = tuple(available_methods())
