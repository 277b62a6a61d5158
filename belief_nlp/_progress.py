"""Progress for long work: a tqdm bar on a terminal or in Jupyter, periodic
log lines otherwise (a CI log or a file gets a few lines, not thousands of
carriage returns)."""

from __future__ import annotations

import logging
import sys
import time
from typing import Any

__all__ = ["progress_bar"]

log = logging.getLogger("belief_nlp.progress")


def _in_notebook() -> bool:
    """A running Jupyter kernel (not merely an imported ipykernel module)."""
    ipython = sys.modules.get("IPython")
    if ipython is None:
        return False
    shell = ipython.get_ipython() if hasattr(ipython, "get_ipython") else None
    return shell is not None and "IPKernelApp" in getattr(shell, "config", {})


def _interactive() -> bool:
    if _in_notebook():                             # Jupyter: tqdm.auto draws a widget
        return True
    stream = sys.stderr
    return bool(getattr(stream, "isatty", lambda: False)())


class _LogProgress:
    """The part of tqdm's interface we use, as log lines every ``every`` seconds."""

    def __init__(self, total: int, desc: str, unit: str, every: float = 5.0):
        self.total, self.desc, self.unit, self.every = total, desc, unit, every
        self.n = 0
        self.postfix = ""
        self.t0 = self.t_last = time.perf_counter()

    def update(self, n: int = 1) -> None:
        self.n += n
        now = time.perf_counter()
        if now - self.t_last >= self.every:
            self.t_last = now
            log.info("%s: %d/%d %s%s (%.0f s)", self.desc, self.n, self.total, self.unit,
                     f", {self.postfix}" if self.postfix else "", now - self.t0)

    def set_postfix(self, **kw: Any) -> None:
        self.postfix = ", ".join(f"{k}={v}" for k, v in kw.items())

    def close(self) -> None:
        log.info("%s: done, %d %s in %.1f s%s", self.desc, self.n, self.unit, time.perf_counter() - self.t0,
                 f" ({self.postfix})" if self.postfix else "")


def progress_bar(total: int, desc: str, unit: str = "it", **kw: Any):
    """A tqdm bar when stderr is a terminal or a notebook runs us, else a logger
    that writes a line every few seconds."""
    if _interactive():
        from tqdm.auto import tqdm

        return tqdm(total=total, desc=desc, unit=unit, **kw)
    return _LogProgress(total, desc, unit)
