"""Built-in smoothing methods; importing a module registers it (one file per method)."""

from . import ccp, ipopt  # noqa: F401, I001 - registration order: ccp, ipopt, auto, sqp
from . import auto  # noqa: F401
from . import sqp  # noqa: F401
from . import fatrop  # noqa: F401

__all__ = ["auto", "ccp", "fatrop", "ipopt", "sqp"]
