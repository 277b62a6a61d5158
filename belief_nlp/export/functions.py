"""Single CasADi functions of the belief model (the per-hazard exports).

Every function here is a named ``casadi.Function`` built from ``SX``
symbols, so it can be called on ``SX`` (it is inlined: code generation and
``expand`` see plain expressions), on ``MX`` (``casadi.Opti``) or on
numbers, and saved with ``Function.save(file)`` / loaded with
``casadi.Function.load(file)`` (see :func:`save_functions`).

Units: SI throughout. Positions x and face offsets b in metres; covariances
P, P_hat, W in m^2; sensing information S in 1/m^2; face normals A
dimensionless (unit rows, as :class:`~belief_nlp.polytope.Polytope` stores
them); certificates lam in 1/m; information in nats. Margins are
dimensionless ("squared Mahalanobis distance minus chi2" for clearances)
except target containment, in metres. Every margin reads ``>= 0`` = safe.

For MPC stacks prefer the stacked bundles of :mod:`.bundle` (all hazards in
one function, obstacle data as parameters, certificate bounds shipped).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np

from ..errors import ValidationError
from ..model import terms
from ..scenario import Scenario, load_scenario

__all__ = [
    "belief_predict", "belief_update", "information_cost", "ellipse_clearance", "transition_clearance",
    "target_containment", "export_functions", "save_functions", "load_functions",
]

def _check_dim(d: Any) -> int:
    if not isinstance(d, (int, np.integer)) or isinstance(d, bool) or d < 1:
        raise ValidationError("d", f"must be a positive integer, got {d!r}")
    return int(d)


# ------------------------------------------------------------ belief maths
def belief_predict(d: int = 2, name: str = "belief_predict") -> ca.Function:
    """(P [m^2], W [m^2]) -> (P_hat [m^2]): the prior after one step, P + W."""
    d = _check_dim(d)
    P = ca.SX.sym("P", d, d)
    W = ca.SX.sym("W", d, d)
    return ca.Function(name, [P, W], [terms.predict(P, W)], ["P", "W"], ["P_hat"])


def belief_update(d: int = 2, name: str = "belief_update") -> ca.Function:
    """(P_hat [m^2], S [1/m^2]) -> (P [m^2]): the posterior (P_hat^-1 + S)^-1."""
    d = _check_dim(d)
    Ph = ca.SX.sym("P_hat", d, d)
    S = ca.SX.sym("S", d, d)
    return ca.Function(name, [Ph, S], [terms.update_cov(Ph, S)], ["P_hat", "S"], ["P"])


def information_cost(d: int = 2, name: str = "information_cost") -> ca.Function:
    """(P_hat [m^2], S [1/m^2]) -> (nats): 1/2 log det(I + P_hat S), which equals
    1/2 log det P_hat - 1/2 log det P for P = belief_update(P_hat, S)."""
    d = _check_dim(d)
    Ph = ca.SX.sym("P_hat", d, d)
    S = ca.SX.sym("S", d, d)
    return ca.Function(name, [Ph, S], [terms.information_cov(Ph, S)], ["P_hat", "S"], ["nats"])


def _fixed_or_inputs(d: int, A: Any, b: Any, n_faces: int | None) -> tuple[ca.SX | ca.DM, ca.SX | ca.DM, list, list]:
    if (A is None) != (b is None):
        raise ValidationError("A", "give both A and b (fixed at export time) or neither (inputs)")
    if A is not None:
        A = np.atleast_2d(np.asarray(A, float))
        b = np.atleast_1d(np.asarray(b, float))
        if A.shape[1] != d or b.shape != (A.shape[0],):
            raise ValidationError("A", f"A must be (f, {d}) and b (f,), got {A.shape} and {b.shape}")
        return ca.DM(A), ca.DM(b), [], []
    if n_faces is None or not isinstance(n_faces, (int, np.integer)) or n_faces < 1:
        raise ValidationError("n_faces", f"give the number of faces when A and b are inputs, got {n_faces!r}")
    As = ca.SX.sym("A", int(n_faces), d)
    bs = ca.SX.sym("b", int(n_faces))
    return As, bs, [As, bs], ["A", "b"]


def _clearance_setup(d: Any, chi2: Any, A: Any, b: Any, n_faces: int | None):
    """Checked (d, chi2) and the polytope as constants or as extra inputs."""
    d = _check_dim(d)
    if chi2 is None or not chi2 > 0:
        raise ValidationError("chi2", f"must be a number > 0, got {chi2!r}")
    return (d, float(chi2)) + _fixed_or_inputs(d, A, b, n_faces)


def ellipse_clearance(d: int = 2, chi2: float | None = None, A: Any = None, b: Any = None,
                      n_faces: int | None = None, name: str = "ellipse_clearance") -> ca.Function:
    """Lemma-1 clearance of the ellipse E(x, P) from the polytope {A y <= b}.

    Inputs x [m] (d), P [m^2] (d, d), lam [1/m] (f) and, unless A and b are
    fixed here, A (f, d) and b [m] (f). Output ``margin`` = -lam^T A P A^T lam
    + 2 lam^T (A x - b) - chi2: for every lam >= 0 a lower bound on the
    squared Mahalanobis distance minus chi2, equal to it at the best lam.
    ``chi2`` is the squared confidence radius (required).
    """
    d, chi2, A_, b_, extra, extra_names = _clearance_setup(d, chi2, A, b, n_faces)
    x = ca.SX.sym("x", d)
    P = ca.SX.sym("P", d, d)
    lam = ca.SX.sym("lam", int(A_.shape[0]))
    m = terms.collision_margin_cov(x, P, lam, A_, b_, chi2)
    return ca.Function(name, [x, P, lam] + extra, [m], ["x", "P", "lam"] + extra_names, ["margin"])


def transition_clearance(d: int = 2, chi2: float | None = None, A: Any = None, b: Any = None,
                         n_faces: int | None = None, name: str = "transition_clearance") -> ca.Function:
    """Theorem-1 clearance of the transition (x_prev, P_prev) -> x_next under noise W.

    Inputs x_prev [m], P_prev [m^2] (the posterior at the start), x_next [m],
    W [m^2] (the step's process noise), lam [1/m] (f) -- one lam for both
    ends -- and A, b unless fixed here. Outputs ``margin_start`` (Lemma 1 at
    x_prev, P_prev) and ``margin_end`` (at x_next, P_prev + W); the whole
    transition x(s), P(s) = P_prev + s W, s in [0, 1], is clear iff both are
    >= 0 for some lam >= 0 (Theorem 1 with C5).
    """
    d, chi2, A_, b_, extra, extra_names = _clearance_setup(d, chi2, A, b, n_faces)
    x0 = ca.SX.sym("x_prev", d)
    P0 = ca.SX.sym("P_prev", d, d)
    x1 = ca.SX.sym("x_next", d)
    W = ca.SX.sym("W", d, d)
    lam = ca.SX.sym("lam", int(A_.shape[0]))
    m0 = terms.collision_margin_cov(x0, P0, lam, A_, b_, chi2)
    m1 = terms.collision_margin_cov(x1, terms.predict(P0, W), lam, A_, b_, chi2)
    return ca.Function(name, [x0, P0, x1, W, lam] + extra, [m0, m1],
                       ["x_prev", "P_prev", "x_next", "W", "lam"] + extra_names, ["margin_start", "margin_end"])


def target_containment(A: Any, b: Any, chi2: float, name: str = "target_containment") -> ca.Function:
    """(x [m], P [m^2]) -> (margins [m], one per face of the target {A y <= b}):
    b_n - a_n^T x - chi sqrt(a_n^T P a_n); all >= 0 iff E(x, P) lies in the target."""
    A = np.atleast_2d(np.asarray(A, float))
    b = np.atleast_1d(np.asarray(b, float))
    if b.shape != (A.shape[0],):
        raise ValidationError("b", f"must have one entry per row of A ({A.shape[0]}), got {b.shape}")
    if not chi2 > 0:
        raise ValidationError("chi2", f"must be a number > 0, got {chi2!r}")
    d = A.shape[1]
    x = ca.SX.sym("x", d)
    P = ca.SX.sym("P", d, d)
    m = ca.vertcat(*[terms.target_margin_cov(x, P, ca.DM(a), float(bn), float(chi2)) for a, bn in zip(A, b)])
    return ca.Function(name, [x, P], [m], ["x", "P"], ["margins"])


def _slug(text: str) -> str:
    return re.sub(r"[^0-9a-zA-Z]+", "_", text).strip("_").lower() or "hazard"


def export_functions(scenario: Scenario | str) -> dict[str, ca.Function]:
    """Every exported function for one scenario, chi2 and polytopes fixed.

    Keys: "belief_predict", "belief_update", "information_cost",
    "target_containment", and per hazard j (obstacles, then domain walls, the
    order of ``scenario.hazards``) "clearance_<name>" (the Lemma-1 form) and
    "transition_<name>" (the Theorem-1 form), e.g. "transition_obstacle_1",
    "transition_wall_0". Function names equal the keys.
    """
    sc = load_scenario(scenario) if isinstance(scenario, str) else scenario
    d = sc.dim
    out = {
        "belief_predict": belief_predict(d),
        "belief_update": belief_update(d),
        "information_cost": information_cost(d),
        "target_containment": target_containment(sc.target.A, sc.target.b, sc.chi2),
    }
    for h in sc.hazards:
        s = _slug(h.name)
        out[f"clearance_{s}"] = ellipse_clearance(d, sc.chi2, h.A, h.b, name=f"clearance_{s}")
        out[f"transition_{s}"] = transition_clearance(d, sc.chi2, h.A, h.b, name=f"transition_{s}")
    return out


def save_functions(functions: dict[str, ca.Function], directory: str | Path) -> list[Path]:
    """Save each function to ``directory/<key>.casadi`` (CasADi serialisation);
    :func:`load_functions` reads them back."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for key, fn in functions.items():
        p = directory / f"{key}.casadi"
        fn.save(str(p))
        written.append(p)
    return written


def load_functions(directory: str | Path) -> dict[str, ca.Function]:
    """The functions saved by :func:`save_functions`, keyed by file stem."""
    return {p.stem: ca.Function.load(str(p)) for p in sorted(Path(directory).glob("*.casadi"))}
