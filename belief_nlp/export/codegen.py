"""C code of a bundle and its derivatives (:func:`generate`)."""

from __future__ import annotations

from pathlib import Path

import casadi as ca

from ..errors import ValidationError
from .bundle import SafetyBundle, TerminalBundle

__all__ = ["generate"]


def generate(bundle: SafetyBundle | TerminalBundle, directory: str | Path, name: str | None = None,
             hessians: bool = True) -> Path:
    """Write ``directory/<name>.c`` with the bundle's function, the Jacobian of
    ``g`` with respect to every input (CasADi's ``jac_<fn>``) and, with
    ``hessians``, the Hessian of ``mu^T g`` (``hess_<fn>``: Lagrangian
    weights ``mu`` as an extra input) -- what an SQP or interior-point
    solver needs. Compile with e.g. ``gcc -fPIC -shared -O2 f.c -o f.so``
    and load with ``casadi.external(fn_name, "f.so")``. Returns the file.
    """
    if not isinstance(bundle, (SafetyBundle, TerminalBundle)):
        raise ValidationError("bundle", f"must be a SafetyBundle or TerminalBundle, got {type(bundle).__name__}")
    fn = bundle.function
    name = name or fn.name()
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    ins = [ca.SX.sym(fn.name_in(i), fn.sparsity_in(i)) for i in range(fn.n_in())]
    g = fn.call(ins)[0]
    x = ca.vertcat(*[ca.vec(v) for v in ins])
    jac = ca.Function(f"jac_{fn.name()}", ins, [ca.jacobian(g, x)], fn.name_in(), ["jac_g"])
    cg = ca.CodeGenerator(f"{name}.c", {"with_header": True})
    cg.add(fn)
    cg.add(jac)
    if hessians:
        mu = ca.SX.sym("mu", g.shape[0])
        H = ca.hessian(ca.dot(mu, g), x)[0]
        cg.add(ca.Function(f"hess_{fn.name()}", ins + [mu], [H], fn.name_in() + ["mu"], ["hess"]))
    cg.generate(str(directory) + "/")
    return directory / f"{name}.c"
