"""Built-in smoothing methods; importing a module registers it (one file per method)."""

from . import ccp, ipopt  # noqa: F401

__all__ = ["ccp", "ipopt"]
