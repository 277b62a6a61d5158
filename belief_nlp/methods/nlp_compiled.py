"""Compiled derivative functions in the disk cache (opt-in:
``set_disk_cache(..., compile=True)`` or ``BELIEF_NLP_CACHE_COMPILE=1``).

The disk cache keeps IPOPT's derivative functions as CasADi serialisations,
which a new process reads back in about 0.3 s at K = 20 (a 77k-instruction
Hessian). With compilation on, the process that writes such an entry also
starts a detached background process that generates their C code and builds
a shared library with the system C compiler (about 25 s at K = 20, on one
core; the caller does not wait). Later processes load the library in about a
millisecond instead, and its functions run about a tenth of an IPOPT
iteration faster than CasADi's virtual machine (docs/numerics.md, "Compiled
derivatives").

A library is used only when

* its signed metadata entry (``<name>.cso.pkl``, signed like every entry)
  names the SHA-256 of the library file, and the file has that digest and is
  private to the user -- a library is code, so nothing else is ever loaded;
* every compiled function reproduces, bit for bit, the values the
  serialised function gave at a fixed point when the library was built (the
  C code is compiled without contraction into fused multiply-adds, so it
  rounds as CasADi's virtual machine does).

Otherwise the serialised functions are used, as without compilation.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

from ..model.cache import ENV_COMPILE, DiskCache, _private

__all__ = ["compiler", "load", "compile_entry", "compile_all", "start"]

log = logging.getLogger("belief_nlp.cache")

#: the C compiler's flags: -O1 halves the Hessian's evaluation time against
#: CasADi's virtual machine for 11 s more compilation than -O0 at K = 20; no
#: contraction, so the C code rounds as the virtual machine
CFLAGS = ("-O1", "-ffp-contract=off", "-fPIC", "-shared")
#: a lock older than this is taken to belong to a compile process that died
STALE_LOCK_S = 1800.0
#: after a failed build, processes do not try that entry again for this long
RETRY_AFTER_S = 86400.0


def compiler() -> str | None:
    """The C compiler: ``$CC``, else ``cc`` or ``gcc`` on the PATH; None when none."""
    for name in (os.environ.get("CC"), "cc", "gcc"):
        if name and (found := shutil.which(name)):
            return found
    return None


def _library(disk: DiskCache, name: str) -> Path:
    return disk.dir / f"{name}.lib.so"


def _failed(directory: str | Path, name: str) -> Path:
    """Marker of a failed build (a compiler error would otherwise be repeated by every process)."""
    return Path(directory) / f".{name}.failed"


def _fingerprint(functions: dict[str, ca.Function]) -> tuple[dict, dict]:
    """A fixed point per function and its output values there (nonzeros)."""
    rng = np.random.default_rng(0)
    points, values = {}, {}
    for option, f in functions.items():
        args = [rng.uniform(0.5, 1.5, f.nnz_in(i)) for i in range(f.n_in())]
        points[option] = args
        values[option] = _values(f, args)
    return points, values


def _values(f: ca.Function, args: list[np.ndarray]) -> list[np.ndarray]:
    dms = [ca.DM(f.sparsity_in(i), a) for i, a in enumerate(args)]
    return [np.array(out.nonzeros(), dtype=float) for out in f.call(dms)]


def _same(a: list[np.ndarray], b: list[np.ndarray]) -> bool:
    return len(a) == len(b) and all(x.shape == y.shape and np.array_equal(x, y, equal_nan=True) for x, y in zip(a, b))


def load(disk: DiskCache, name: str) -> dict[str, ca.Function] | None:
    """The compiled derivative functions of entry ``name`` ({option: function}),
    or None when there is no library or it fails a check (module doc)."""
    meta = disk.load(name, kind="cso")
    lib = _library(disk, name)
    if not isinstance(meta, dict) or not lib.exists():
        return None
    try:
        if not _private(lib) or hashlib.sha256(lib.read_bytes()).hexdigest() != meta["sha256"]:
            log.warning("ignoring compiled entry %s: not the library that was signed", lib.name)
            return None
        functions = {option: ca.external(fname, str(lib)) for option, fname in meta["functions"].items()}
        for option, f in functions.items():
            if not _same(_values(f, meta["points"][option]), meta["values"][option]):
                log.warning("ignoring compiled entry %s: %s differs from the serialised function", lib.name, option)
                return None
        os.utime(lib)                   # recently used, as a loaded entry (size cap)
        return functions
    except Exception as exc:  # a broken library is never fatal: the serialised functions serve
        log.warning("ignoring compiled entry %s: %s", lib.name, exc)
        return None


def compile_entry(directory: str | Path, name: str, cc: str | None = None) -> Path | None:
    """Build the library of the serialised derivative entry ``name`` in the
    cache folder ``directory`` and sign it; returns its path (None when the
    entry is missing or no C compiler is found). Runs in the background
    process :func:`start` launches; callable directly (tests, scripts)."""
    disk = DiskCache(directory)
    functions = disk.load(name, kind="nlp")
    cc = cc or compiler()
    if not isinstance(functions, dict) or not functions or cc is None:
        return None
    with tempfile.TemporaryDirectory(dir=disk.dir, prefix=".tmp-build-") as tmp:
        gen = ca.CodeGenerator("derivatives.c", {"with_header": False})
        for f in functions.values():
            gen.add(f)
        gen.generate(tmp + os.sep)
        built = Path(tmp) / "derivatives.so"
        subprocess.run([cc, *CFLAGS, str(Path(tmp) / "derivatives.c"), "-o", str(built), "-lm"], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        os.chmod(built, 0o600)
        lib = _library(disk, name)
        os.replace(built, lib)
    points, values = _fingerprint(functions)
    meta = {"sha256": hashlib.sha256(lib.read_bytes()).hexdigest(),
            "functions": {option: f.name() for option, f in functions.items()},
            "points": points, "values": values, "cc": cc, "cflags": CFLAGS}
    disk.save(name, meta, kind="cso")
    return lib


def compile_all(disk: DiskCache, progress: bool = True) -> tuple[int, list[str]]:
    """Build, in this process, the library of every serialised derivative
    entry in ``disk`` that has none (``belief-nlp cache --compile``: e.g. when
    preparing a deployment image); returns (built, names that failed)."""
    from .._progress import progress_bar

    entries = (p.name.split(".")[0] for p in disk.entries() if p.name.endswith(".nlp.pkl"))
    names = sorted(name for name in entries if not _library(disk, name).exists())
    built, failed = 0, []
    bar = progress_bar(len(names), "compiling", unit="entry", disable=not progress or not names)
    try:
        for name in names:
            try:
                lib = compile_entry(disk.dir, name)
            except Exception as exc:     # one bad entry does not stop the others
                log.warning("could not compile cache entry %s: %s", name, exc)
                lib = None
            if lib is None:
                failed.append(name)
            else:
                built += 1
            bar.update(1)
    finally:
        bar.close()
    return built, failed


def start(disk: DiskCache, name: str) -> bool:
    """Start the background build of entry ``name``'s library unless it exists,
    another process is building it, a build of it failed in the last day, or
    there is no C compiler; True when started. The caller goes on at once."""
    if compiler() is None or not sys.executable or _library(disk, name).exists():
        return False                     # (no sys.executable: an embedded interpreter cannot start one)
    lock, failed = disk.dir / f".{name}.compiling", _failed(disk.dir, name)
    try:
        if failed.exists() and time.time() - failed.stat().st_mtime < RETRY_AFTER_S:
            return False
        if lock.exists() and time.time() - lock.stat().st_mtime > STALE_LOCK_S:
            lock.unlink()
        fd = os.open(lock, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        os.close(fd)
    except OSError:                      # someone else is building it (or the folder is gone)
        return False
    env = {**os.environ, ENV_COMPILE: "0"}
    try:
        subprocess.Popen([sys.executable, "-m", __name__, str(disk.dir), name, str(lock)], env=env,
                         stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         start_new_session=True, close_fds=True)
    except OSError as exc:               # never fatal to the caller's solve
        log.warning("could not start the compilation of cache entry %s: %s", name, exc)
        lock.unlink(missing_ok=True)
        return False
    return True


def _main(argv: list[str]) -> int:
    directory, name, lock = argv
    try:
        os.nice(10)                      # the user's own work comes first
    except (OSError, AttributeError):    # AttributeError: no os.nice (Windows)
        pass
    try:
        return 0 if compile_entry(directory, name) is not None else 1
    except Exception as exc:             # a compiler error: not tried again by every process
        log.warning("could not compile cache entry %s: %s", name, exc)
        _failed(directory, name).touch(mode=0o600)
        return 1
    finally:
        Path(lock).unlink(missing_ok=True)


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1:]))
