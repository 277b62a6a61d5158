"""Input limits, and bounded readers for the files the library loads.

Every limit below is part of the documented contract: input beyond it is
rejected up front with :class:`~belief_nlp.errors.ValidationError` (or its
subclass :class:`~belief_nlp.errors.ScenarioFileError` for files), naming the
field, instead of running for minutes or failing deep inside numpy, scipy or
a solver.

========================  ==============  ==========================================
limit                     value           applies to
========================  ==============  ==========================================
MAX_SCENARIO_FILE_BYTES   8 MiB           scenario files (TOML / JSON)
MAX_DATA_FILE_BYTES       128 MiB         path and result files (JSON / NPZ, on disk)
MAX_UNPACKED_BYTES        512 MiB         NPZ members, uncompressed, together
MAX_NESTING               32              arrays / tables inside one another
MAX_FILE_INTEGER          2**53           integers in files (exact in a float)
MAX_COORDINATE            1e6 m           polytope vertices, box bounds, the start
                                          mean; half-space offsets (distances of the
                                          faces from the origin) up to sqrt(d) * 1e6 m
MAX_VARIANCE              1e12 m^2        eigenvalues of start.P, noise.W, noise.W_rate
MIN_NOISE_VARIANCE        1e-20 m^2       smallest eigenvalue of noise.W, noise.W_rate
MAX_ALPHA                 1e6             information weight alpha
MAX_CHI2                  1e4             chi2 (confidence < 1 gives at most ~80)
MAX_HORIZON               10000           horizon.K
MAX_OBSTACLES             1000            obstacles in one scenario
MAX_POLYTOPE_VERTICES     20000           vertices of one polytope
MAX_POLYTOPE_FACES        10000           half-spaces given as A, b (each costs LP rows)
MAX_DIMENSION             6               dimension of a polytope (a box has 2**d corners)
MAX_VERIFY_SAMPLES        10001           verify(n_samples=..., n_refine=...)
MAX_PLANNER_NODES         1000000         plan(n_nodes=...)
MAX_NAME_LENGTH           4096            a scenario name or file name given as text
========================  ==============  ==========================================

The magnitude limits keep every derived quantity (squared distances, chi2
times a variance, log-determinants) far from float overflow: a domain of
2e6 m squared is 4e12, times chi2 <= 1e4 and divided by a variance >= 1e-20
stays below 1e37.
"""

from __future__ import annotations

import json
import tomllib
import zipfile
from pathlib import Path
from typing import Any

from .errors import ScenarioFileError

__all__ = [
    "MAX_SCENARIO_FILE_BYTES", "MAX_DATA_FILE_BYTES", "MAX_UNPACKED_BYTES", "MAX_NESTING", "MAX_FILE_INTEGER",
    "MAX_COORDINATE", "MAX_VARIANCE", "MIN_NOISE_VARIANCE", "MAX_ALPHA", "MAX_CHI2", "MAX_HORIZON",
    "MAX_OBSTACLES", "MAX_POLYTOPE_VERTICES", "MAX_POLYTOPE_FACES", "MAX_DIMENSION", "MAX_VERIFY_SAMPLES",
    "MAX_PLANNER_NODES", "MAX_NAME_LENGTH", "read_file", "parse_document", "check_document", "load_json", "check_npz",
]

MAX_SCENARIO_FILE_BYTES = 8 * 2**20
MAX_DATA_FILE_BYTES = 128 * 2**20
MAX_UNPACKED_BYTES = 512 * 2**20
MAX_NESTING = 32
MAX_FILE_INTEGER = 2**53
MAX_COORDINATE = 1e6
MAX_VARIANCE = 1e12
MIN_NOISE_VARIANCE = 1e-20
MAX_ALPHA = 1e6
MAX_CHI2 = 1e4
MAX_HORIZON = 10_000
MAX_OBSTACLES = 1000
MAX_POLYTOPE_VERTICES = 20_000
MAX_DIMENSION = 6
MAX_POLYTOPE_FACES = 10_000
MAX_VERIFY_SAMPLES = 10_001
MAX_PLANNER_NODES = 1_000_000
MAX_NAME_LENGTH = 4096


def _mib(n: int) -> str:
    return f"{n / 2**20:g} MiB"


def _checked_file(path: str | Path, field: str, limit: int, what: str = "file") -> Path:
    """``path`` as a Path, after checking that it is a regular file of at most ``limit`` bytes."""
    try:
        p = Path(path)
        if not p.exists():
            raise ScenarioFileError(field, f"no such {what}: {_short(path)}")
        if not p.is_file():
            raise ScenarioFileError(field, f"not a file: {_short(path)}")
        size = p.stat().st_size
    except ScenarioFileError:
        raise
    except (OSError, ValueError) as exc:  # name too long; ValueError: embedded NUL
        raise ScenarioFileError(field, f"cannot read {_short(path)}: {exc}") from exc
    if size > limit:
        raise ScenarioFileError(field, f"{_short(path)} is {_mib(size)}, larger than the limit of {_mib(limit)}")
    return p


def read_file(path: str | Path, field: str = "file", limit: int = MAX_DATA_FILE_BYTES, what: str = "file") -> bytes:
    """The bytes of ``path``, refusing files larger than ``limit`` before reading them.

    Every fault (missing, a directory, unreadable, a name the OS rejects,
    too large) raises :class:`ScenarioFileError` naming ``field``; ``what``
    names the kind of file in the "no such ..." message.
    """
    p = _checked_file(path, field, limit, what)
    try:
        with open(p, "rb") as fh:
            # one byte more than allowed: the file may have grown since stat()
            raw = fh.read(limit + 1)
    except OSError as exc:
        raise ScenarioFileError(field, f"cannot read {_short(path)}: {exc}") from exc
    if len(raw) > limit:
        raise ScenarioFileError(field, f"{_short(path)} is larger than the limit of {_mib(limit)}")
    return raw


def _short(path: Any, n: int = 200) -> str:
    """A file name for a message, cut so that a 5000-character name gives a readable line."""
    s = str(path)
    return s if len(s) <= n else f"{s[:n]}... ({len(s)} characters)"


def parse_document(raw: bytes | str, fmt: str, source: str, field: str = "file") -> Any:
    """Parse JSON or TOML text, then :func:`check_document` it.

    Malformed text, nesting deep enough to exhaust the parser's recursion, an
    integer the parser refuses (more than 4300 digits) and a document too big
    for memory all raise :class:`ScenarioFileError` naming ``field``.
    """
    name = fmt.upper()
    try:
        text = raw.decode("utf-8") if isinstance(raw, bytes) else raw
        data = json.loads(text) if fmt == "json" else tomllib.loads(text)
    except RecursionError as exc:
        raise ScenarioFileError(field, f"{_short(source)}: arrays/tables nested too deeply "
                                       f"(the limit is {MAX_NESTING} levels)") from exc
    except MemoryError as exc:
        raise ScenarioFileError(field, f"{_short(source)}: too large to parse") from exc
    except ValueError as exc:  # JSONDecodeError, TOMLDecodeError, UnicodeDecodeError, int digits
        raise ScenarioFileError(field, f"{_short(source)}: malformed {name}: {str(exc)[:300]}") from exc
    check_document(data, source, field)
    return data


def check_document(data: Any, source: str = "document", field: str = "file") -> None:
    """Reject a parsed document nested deeper than :data:`MAX_NESTING` or
    holding an integer beyond :data:`MAX_FILE_INTEGER` (it would become an
    object array in numpy, or overflow when turned into a float).

    The walk is iterative, so it cannot itself run out of stack.
    """
    if not isinstance(data, (dict, list)):
        return
    stack: list[tuple[Any, int, str]] = [(data, 0, "")]
    while stack:
        node, depth, where = stack.pop()
        if depth > MAX_NESTING:
            raise ScenarioFileError(field, f"{_short(source)}: arrays/tables nested more than {MAX_NESTING} "
                                           f"levels deep (at {where or 'the top level'})")
        items = node.items() if isinstance(node, dict) else enumerate(node)
        for key, value in items:
            if isinstance(value, (dict, list)):
                label = f"{where}.{key}" if isinstance(key, str) else f"{where}[{key}]"
                stack.append((value, depth + 1, label.lstrip(".")))
            elif isinstance(value, int) and not isinstance(value, bool) and abs(value) > MAX_FILE_INTEGER:
                label = f"{where}.{key}" if isinstance(key, str) else f"{where}[{key}]"
                raise ScenarioFileError(label.lstrip(".") or field,
                                        f"integer with {len(str(abs(value)))} digits is out of range "
                                        f"(|n| <= 2**53 = {MAX_FILE_INTEGER})")


def load_json(path: str | Path, field: str = "file", limit: int = MAX_DATA_FILE_BYTES) -> Any:
    """Read and parse a JSON file within the size and nesting limits."""
    return parse_document(read_file(path, field, limit), "json", str(path), field)


def check_npz(path: str | Path, field: str = "file") -> None:
    """Refuse an NPZ file that is not a zip archive, or whose members would
    unpack to more than :data:`MAX_UNPACKED_BYTES` (a compressed bomb),
    before numpy reads any of it. The file size is checked like any other."""
    _checked_file(path, field, MAX_DATA_FILE_BYTES)
    try:
        with zipfile.ZipFile(path) as zf:
            total = sum(info.file_size for info in zf.infolist())
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise ScenarioFileError(field, f"{_short(path)}: not an NPZ (zip) file: {exc}") from exc
    if total > MAX_UNPACKED_BYTES:
        raise ScenarioFileError(field, f"{_short(path)}: unpacks to {_mib(total)}, more than the limit of "
                                       f"{_mib(MAX_UNPACKED_BYTES)}")
