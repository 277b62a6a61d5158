"""Smoothing methods as plug-ins: each registers itself with a name, its own
default iteration limit, an option schema and a ``run`` function.

Adding a method is one new file that calls :func:`register` (see
``belief_nlp/methods/ccp.py``) plus its tests; the CLI, :func:`compare` and
studies list :func:`available_methods` and need no edit. :func:`smooth`
also takes a plain callable, as ``scipy.optimize.minimize`` does.

:data:`DEFAULT_METHOD` ("auto": IPOPT on the exact NLP, CCP from the best
safe point as its fallback) is what :func:`smooth` and the command line run
when no method is named.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass, field
from typing import Any, Callable

from ..errors import ValidationError
from ..scenario_validate import _is_real

__all__ = ["DEFAULT_METHOD", "Option", "Method", "register", "available_methods", "available_solvers", "get_method",
           "resolve_method", "count", "nonneg", "real"]

# CasADi nlpsol plug-ins a method may run (the ones CasADi's wheels can ship)
_NLP_SOLVERS = ("ipopt", "fatrop", "uno", "madnlp", "sqpmethod", "blocksqp", "knitro", "snopt", "worhp", "bonmin")

#: The method used when none is named (``smooth``, the CLI's ``--method``, the demo).
DEFAULT_METHOD = "auto"


def count(v: Any) -> str | None:
    """An :class:`Option` check: an integer >= 0 (not a bool)."""
    return None if isinstance(v, int) and not isinstance(v, bool) and v >= 0 else "must be an integer >= 0"


def real(v: Any) -> float | None:
    """``v`` as a float when it is a number (not a bool) a float can hold;
    None otherwise (an int beyond 1.8e308 passed Python's comparisons and
    overflowed later, in the solver's arithmetic: found by the fuzz test)."""
    if not _is_real(v):
        return None
    try:
        return float(v)
    except OverflowError:
        return None


def nonneg(v: Any) -> str | None:
    """An :class:`Option` check: a number >= 0 (not a bool)."""
    r = real(v)
    return None if r is not None and r >= 0 else "must be a number >= 0"


@dataclass(frozen=True)
class Option:
    """One method option: its default, a check and a line of documentation.

    Parameters
    ----------
    default : Any
        The value used when the caller does not give the option.
    doc : str
        One line for listings (``belief-nlp methods``, the reference).
    check : callable, optional
        ``check(value) -> str | None``: an error text (the problem) for a bad
        value, None when the value is fine. Without it any value is taken.
    """

    default: Any
    doc: str
    check: Callable[[Any], str | None] | None = None


@dataclass(frozen=True)
class Method:
    """A registered smoothing method.

    Parameters
    ----------
    name : str
        What ``smooth(method=...)`` takes: a word (letters, digits, ``_``, ``-``).
    run : callable
        ``run(problem, **options) -> Outcome``; ``problem`` is a
        :class:`~belief_nlp.SmoothingProblem`, the result an
        :class:`~belief_nlp.Outcome`.
    max_iter : int
        Default iteration limit (what one iteration is: ``iteration``).
    options : dict of str to Option, optional
        The method's own keyword options, validated (:meth:`validate`)
        before any work.
    description : str, optional
        One line for listings.
    iteration : str, optional
        What one iteration is, for listings (default ``"iteration"``).
    default_solver : str or None, optional
        The solver used when ``smooth`` gets ``solver=None``; None when the
        method takes no ``solver``.
    check_solver : callable, optional
        ``check_solver(solver) -> str | None``: an error text for a solver
        the method cannot use, for methods whose solvers are discovered at
        run time.

    See Also
    --------
    belief_nlp.register_method : add it to the registry.
    """

    name: str
    run: Callable[..., Any]
    max_iter: int
    options: dict = field(default_factory=dict)
    description: str = ""
    iteration: str = "iteration"
    default_solver: str | None = None
    check_solver: Callable[[str], str | None] | None = None

    def validate(self, options: dict) -> dict:
        """The options with defaults filled in.

        Parameters
        ----------
        options : dict
            Keyword options given by the caller.

        Returns
        -------
        dict
            Every option of the method, given or default.

        Raises
        ------
        ValidationError
            For an unknown name or a value its :class:`Option` check rejects;
            the error names the option.
        """
        unknown = sorted(set(options) - set(self.options))
        if unknown:
            known = ", ".join(sorted(self.options)) or "none"
            raise ValidationError(unknown[0], f"is not an option of method {self.name!r} (its options: {known})")
        out = {}
        for name, opt in self.options.items():
            value = options.get(name, opt.default)
            if name in options and opt.check is not None:
                problem = opt.check(value)
                if problem:
                    raise ValidationError(name, problem)
            out[name] = value
        return out


_REGISTRY: dict[str, Method] = {}


def register(method: Method, *, replace: bool = False) -> Method:
    """Add a smoothing method to the registry (``bn.register_method``).

    After it, ``smooth(method=method.name)``, :func:`compare`, studies and the
    command line's ``--method`` know the method.

    Parameters
    ----------
    method : Method
        The method to add.
    replace : bool, optional
        Redefine a name that is registered already (default False).

    Returns
    -------
    Method
        ``method`` itself (so that a module can write ``M = register(Method(...))``).

    Raises
    ------
    ValidationError
        When ``method`` is not a :class:`Method`, its name is not a word, or
        the name is taken and ``replace`` is False.
    """
    if not isinstance(method, Method):
        raise ValidationError("method", f"must be a Method, got {type(method).__name__}")
    if not method.name or not method.name.replace("_", "").replace("-", "").isalnum():
        raise ValidationError("method.name", f"must be a non-empty word, got {method.name!r}")
    if method.name in _REGISTRY and not replace and _REGISTRY[method.name] is not method:
        raise ValidationError("method.name", f"{method.name!r} is registered already (pass replace=True)")
    _REGISTRY[method.name] = method
    return method


def unregister(name: str) -> None:
    """Remove a method (tests register toy methods and remove them again)."""
    _REGISTRY.pop(name, None)


def available_methods() -> list[str]:
    """Names of the registered smoothing methods.

    Returns
    -------
    list of str
        :data:`DEFAULT_METHOD` first, then the others in registration order
        (the built-ins ``ccp``, ``ipopt``, ``sqp`` before methods registered
        by users).
    """
    names = list(_REGISTRY)
    if DEFAULT_METHOD in names:
        names.remove(DEFAULT_METHOD)
        names.insert(0, DEFAULT_METHOD)
    return names


def available_solvers(method: str | Method = DEFAULT_METHOD) -> list[str]:
    """The solvers ``method`` can use on this machine (qpsolvers' habit).

    Parameters
    ----------
    method : str or Method, optional
        A name from :func:`available_methods` (default :data:`DEFAULT_METHOD`).

    Returns
    -------
    list of str
        Installed solvers the method accepts for ``smooth(..., solver=...)``,
        its default first: for ``ccp`` the CVXPY solvers with PSD and
        exponential cones, for the NLP methods the CasADi plug-ins present.
        A method that names no solver gives [].
    """
    m = resolve_method(method)
    if m.check_solver is None:
        return [m.default_solver] if m.default_solver else []
    import casadi as ca

    from ..model.cvxpy_form import usable_solvers

    names = list(usable_solvers()) + [n for n in _NLP_SOLVERS if ca.has_nlpsol(n)]
    ok = [n for n in names if m.check_solver(n) is None]
    d = m.default_solver
    if d is not None:
        ok.sort(key=lambda n: n.upper() != d.upper())
    return ok


def get_method(name: str) -> Method:
    """The registered smoothing method called ``name``.

    Parameters
    ----------
    name : str
        A name from :func:`available_methods`.

    Returns
    -------
    Method
        Its ``options`` document the method's keyword options.

    Raises
    ------
    ValidationError
        (field ``"method"``) for an unknown name; the message lists the known ones.
    """
    if isinstance(name, str) and name not in _REGISTRY:     # names are case-insensitive, as solver names are
        name = {k.lower(): k for k in _REGISTRY}.get(name.lower(), name)
    if not isinstance(name, str) or name not in _REGISTRY:
        raise ValidationError("method", f"must be one of {available_methods()} or a callable, got {name!r}")
    return _REGISTRY[name]


def resolve_method(method: str | Callable | Method) -> Method:
    """A Method from a name, a Method, or a callable ``fn(problem, **options)``
    (its keyword parameters with defaults become its options)."""
    if isinstance(method, Method):
        return method
    if isinstance(method, str):
        return get_method(method)
    if callable(method):
        opts = {}
        for p in list(inspect.signature(method).parameters.values())[1:]:
            if p.default is not inspect.Parameter.empty:
                opts[p.name] = Option(p.default, "")
        name = getattr(method, "__name__", "custom")
        return Method(name=name, run=method, max_iter=getattr(method, "max_iter", 100), options=opts,
                      description=(inspect.getdoc(method) or "").split("\n")[0])
    raise ValidationError("method", f"must be a method name, a Method or a callable, got {type(method).__name__}")


def iterations_counted(nit: int, method: str) -> str:
    """``"N iterations (each one IPOPT iteration, ...)"``: an iteration count
    that says what it counts (the method's :attr:`Method.iteration`), for
    messages and summaries; ``method`` is a registered name or a result's
    label such as ``"auto:ipopt"`` (an unknown name gives the bare count)."""
    count = f"{nit} iteration{'' if nit == 1 else 's'}"
    key = method.split(":")[0] if isinstance(method, str) else ""
    m = _REGISTRY.get(key) or {k.lower(): v for k, v in _REGISTRY.items()}.get(key.lower())
    return count if m is None or m.iteration == "iteration" else f"{count} (each {m.iteration})"
