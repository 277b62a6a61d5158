"""Every public name is documented and listed in the API reference.

Public names: ``belief_nlp.__all__``, the ``__all__`` of the packages the
reference covers (``plotting``, ``export``, ``study``) and of the modules
``belief_nlp.__all__`` re-exports (``belief``, ``geometry``), and the public
methods and properties of every public class. The reference sources are
read as text (``docs/api/*.rst``: autosummary lists and ``.. data::``
entries), so this runs without Sphinx; ``tests/test_docs.py`` builds the
site itself. A class page lists the members that have a docstring
(autodoc ``:members:``), so a member with a docstring is in the reference.

The names of ``belief_nlp.__all__`` carry numpy-style docstrings: a
function documents each of its parameters under ``Parameters`` and what it
gives back under ``Returns``; a class documents its constructor's
parameters under ``Parameters`` or ``Attributes``.
"""

from __future__ import annotations

import importlib
import inspect
import re
from pathlib import Path

import pytest

import belief_nlp

API_DIR = Path(__file__).resolve().parent.parent / "docs" / "api"
PACKAGES = ("belief_nlp", "belief_nlp.plotting", "belief_nlp.export", "belief_nlp.study")

_DIRECTIVE = re.compile(r"^\.\. (\w+(?::\w+)?)::\s*(\S*)\s*$")
_OPTION = re.compile(r"^\s+:[\w-]+:")


def _reference() -> tuple[set[str], dict[str, dict]]:
    """Full names listed in autosummary tables, and ``.. data::`` entries
    ({full name: {"value": text or None, "body": text}}), from docs/api/*.rst."""
    listed: set[str] = set()
    data: dict[str, dict] = {}
    for page in sorted(API_DIR.glob("*.rst")):
        module = ""
        lines = page.read_text().splitlines()
        i = 0
        while i < len(lines):
            match = _DIRECTIVE.match(lines[i])
            i += 1
            if not match:
                continue
            kind, arg = match.groups()
            if kind in ("module", "currentmodule", "py:module", "py:currentmodule"):
                module = arg
            elif kind == "automodule":
                listed.add(arg)  # a module page: the module itself is listed
                module = module or arg
            elif kind in ("autosummary", "data", "py:data"):
                block = []
                while i < len(lines) and (not lines[i].strip() or lines[i].startswith("   ")):
                    block.append(lines[i])
                    i += 1
                if kind == "autosummary":
                    for entry in block:
                        name = entry.strip()
                        if name and not _OPTION.match(entry):
                            listed.add(name if name.startswith("belief_nlp.") else f"{module}.{name}")
                else:
                    value = next((b.split(":value:", 1)[1].strip() for b in block if ":value:" in b), None)
                    body = " ".join(b.strip() for b in block if b.strip() and not _OPTION.match(b))
                    data[f"{module}.{arg}"] = {"value": value, "body": body}
    return listed, data


LISTED, DATA = _reference()


def _public() -> dict[str, object]:
    """{full name: object} for every public name the reference must cover."""
    out: dict[str, object] = {}
    for package in PACKAGES:
        mod = importlib.import_module(package)
        for name in mod.__all__:
            obj = getattr(mod, name)
            out[f"{package}.{name}"] = obj
    return out


PUBLIC = _public()
MODULES = {name: obj for name, obj in PUBLIC.items() if inspect.ismodule(obj)}
CONSTANTS = {name: obj for name, obj in PUBLIC.items()
             if not (inspect.ismodule(obj) or inspect.isclass(obj) or callable(obj))}


def _own_doc(obj) -> str:
    """The docstring written for ``obj`` (not an inherited or generated one)."""
    doc = obj.__dict__.get("__doc__") if inspect.isclass(obj) else getattr(obj, "__doc__", None)
    doc = inspect.cleandoc(doc or "")
    if inspect.isclass(obj) and re.match(rf"{re.escape(obj.__name__)}\(.*\)$", doc):
        return ""  # what @dataclass writes when the class has none
    return doc


def _documented_objects() -> dict[str, object]:
    """Functions, classes and modules among the public names, and the
    members of the re-exported modules' ``__all__``."""
    out = {name: obj for name, obj in PUBLIC.items() if name not in CONSTANTS}
    for modname, mod in MODULES.items():
        for name in getattr(mod, "__all__", []):
            obj = getattr(mod, name)
            if inspect.isclass(obj) or inspect.isfunction(obj):
                out[f"{modname}.{name}"] = obj
    return out


DOCUMENTED = _documented_objects()


def _members() -> dict[str, object]:
    """Public methods, properties, class- and static methods of the public classes."""
    out: dict[str, object] = {}
    for name, cls in DOCUMENTED.items():
        if not inspect.isclass(cls) or issubclass(cls, BaseException):
            continue
        for attr, value in vars(cls).items():
            if attr.startswith("_"):
                continue
            if isinstance(value, (staticmethod, classmethod)):
                value = value.__func__
            elif isinstance(value, property):
                value = value.fget
            elif hasattr(value, "func") and hasattr(value, "attrname"):  # functools.cached_property
                value = value.func
            if inspect.isfunction(value):
                out[f"{name}.{attr}"] = value
    return out


MEMBERS = _members()


def test_the_reference_sources_are_read():
    # an independent count: each listed name occurs literally in the sources
    text = "\n".join(p.read_text() for p in API_DIR.glob("*.rst"))
    assert len(LISTED) >= 80
    for name in LISTED:
        assert name.rsplit(".", 1)[1] in text
    assert "belief_nlp.smooth" in LISTED and "belief_nlp.export.stage_bundle" in LISTED


@pytest.mark.parametrize("name", sorted(PUBLIC))
def test_public_name_is_in_the_reference(name):
    if name in CONSTANTS:
        assert name in DATA, f"{name} has no '.. data::' entry in docs/api/*.rst"
    else:
        assert name in LISTED, f"{name} is missing from the autosummary lists in docs/api/*.rst"


def test_the_reference_lists_nothing_that_is_not_public():
    stale = sorted((LISTED | set(DATA)) - set(PUBLIC) - set(PACKAGES))
    assert not stale, f"docs/api lists names that are not public (any more): {stale}"


@pytest.mark.parametrize("name", sorted(CONSTANTS))
def test_constant_is_described_with_its_value(name):
    entry = DATA[name]
    assert len(entry["body"]) > 40, f"{name}: its '.. data::' entry says nothing"
    if entry["value"] is not None:
        assert entry["value"] == repr(CONSTANTS[name]), f"{name}: the reference states a stale value"


@pytest.mark.parametrize("name", sorted(DOCUMENTED))
def test_public_object_has_a_docstring(name):
    assert len(_own_doc(DOCUMENTED[name])) > 20, f"{name} has no docstring"


@pytest.mark.parametrize("name", sorted(MEMBERS))
def test_public_member_has_a_docstring(name):
    assert len(_own_doc(MEMBERS[name])) > 10, f"{name} has no docstring"


# ----------------------------------------------------------- numpy style
_HEADER = re.compile(r"^(\w[\w ]*)\n-{3,}$", re.M)
_ENTRY = re.compile(r"^(\*{0,2}\w+(?:\s*,\s*\*{0,2}\w+)*)\s*(?::.*)?$")


def sections(doc: str) -> dict[str, list[str]]:
    """{section title: the names its entries document} of a numpy-style docstring."""
    out: dict[str, list[str]] = {}
    heads = list(_HEADER.finditer(doc))
    for k, head in enumerate(heads):
        end = heads[k + 1].start() if k + 1 < len(heads) else len(doc)
        names = []
        for line in doc[head.end():end].splitlines():
            if not line.strip() or line[0].isspace():
                continue  # a description
            match = _ENTRY.match(line)
            # "name : type" entries give their names; a bare type ("list of dict") itself
            names += [n.strip().lstrip("*") for n in match.group(1).split(",")] if match else [line.strip()]
        out[head.group(1)] = names
    return out


def test_the_section_reader():
    doc = inspect.cleandoc("""Summary.

        Parameters
        ----------
        a, b : int
            Two numbers.
        **options
            More.

        Returns
        -------
        float
            Their sum.
        """)
    assert sections(doc) == {"Parameters": ["a", "b", "options"], "Returns": ["float"]}


def _parameters(obj) -> list[str]:
    target = obj.__init__ if inspect.isclass(obj) else obj
    try:
        sig = inspect.signature(target)
    except (TypeError, ValueError):
        return []
    return [p.name for p in sig.parameters.values() if p.name not in ("self", "cls")]


NUMPY_STYLE = {name: obj for name, obj in PUBLIC.items()
               if name.count(".") == 1 and (inspect.isfunction(obj) or inspect.isclass(obj))
               and not (inspect.isclass(obj) and issubclass(obj, BaseException))}


@pytest.mark.parametrize("name", sorted(NUMPY_STYLE))
def test_top_level_name_has_numpy_sections(name):
    obj = NUMPY_STYLE[name]
    found = sections(_own_doc(obj))
    params = _parameters(obj)
    if inspect.isclass(obj):
        documented = set(found.get("Parameters", [])) | set(found.get("Attributes", []))
    else:
        documented = set(found.get("Parameters", []))
        assert found.get("Returns"), f"{name}: no 'Returns' section"
    missing = [p for p in params if p not in documented]
    assert not missing, f"{name}: parameters {missing} are not documented (numpy-style sections: {sorted(found)})"


def test_the_installed_version_is_the_packages():
    """pyproject.toml reads the version from belief_nlp/_version.py (one place)."""
    from importlib.metadata import version

    import belief_nlp

    assert version("belief-nlp") == belief_nlp.__version__
