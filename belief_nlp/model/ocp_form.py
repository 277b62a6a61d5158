"""The NLP of :mod:`.nlp_form` in stage order, for structure-exploiting
solvers (fatrop): generated from any :class:`~.nlp_form.NLPProblem` whose
variables carry a step label, not written by hand.

A structure-exploiting interior-point solver wants the NLP as an optimal
control problem over stages i = 0..N: variables ``[s_0, u_0, s_1, u_1, ...,
s_N, u_N]`` (states, then controls, of each stage), constraint rows
``[gap_0, path_0, gap_1, path_1, ..., path_N]`` where gap_i closes the gap
to the next stage, ``s_{i+1} - f_i(s_i, u_i) = 0`` (identity on s_{i+1}), and
every other row, and every term of the cost, depends on one stage's (s_i,
u_i) only (a block-diagonal Lagrangian Hessian).

The smoothing NLP couples each step only to its neighbour: the Kalman
equality ties Q_k to Y_{k-1}, a transition's start margin reads x_{k-1} and
Y_{k-1}, the control term ||x_k - x_{k-1}||^2. Here stage i = k - 1 holds
step k: its controls are all of step k's variables (belief, sensing factor,
certificates, and whatever a later NLP adds with a step label), its state a
copy of the step-(k-1) variables that step k's rows and cost terms read
("carried" variables; none at k = 1, where step 0 is data), and the gap rows
are the copies' equalities ``copy - original = 0``. Rows and cost terms that
read steps k - 1 and k are rewritten on the copy. The cost is split into its
additive terms (an expression-tree walk through sums, differences and
constant factors) so that each term lands in one stage.

Step labels: ``nlp.info["stages"]`` (one int in 1..K per variable) when the
NLP supplies them, else the layout of :func:`.nlp_form.build_nlp` read from
the symbols' names (x_k, L_k, M_k (k >= 2) and lam_k, column by column);
variables outside that layout get
the largest step of the rows and cost terms that read them (a per-pair
variable of transition k lands in step k).

A row over the whole path whose additive terms each read one step or two
neighbours -- a risk budget's sum_kj g(tau_kj) <= Delta -- is carried as a
running sum: new variables r_k (step k) with rows r_k = r_{k-1} + (the
terms of step k), and the row itself becomes r_K, with its bounds. Any other
row or term spanning more than two consecutive steps is refused (the
"eliminated" formulation, whose Q_k depends on every earlier step).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable

import casadi as ca
import numpy as np

from ..errors import ValidationError
from .data import Layout
from .nlp_form import NLPProblem

__all__ = ["OCPProblem", "build_ocp", "stage_labels", "additive_terms"]


@dataclass
class OCPProblem:
    """An :class:`~.nlp_form.NLPProblem` in stage order (module doc); it has
    the same attributes, so a solver driver uses either, plus the structure.

    Attributes
    ----------
    source : the NLP it was made from.
    src : (n,) index of the source variable behind each variable here (a
        copy points at its original).
    orig : (n_source,) position here of each source variable (not its copy).
    source_rows : (m_source,) position here of each source row; gap rows are
        the others.
    N, nx, nu, ng : the stage structure (fatrop's manual structure options).
    """

    source: NLPProblem
    z: ca.SX
    p: ca.SX
    f: ca.SX
    g: ca.SX
    lbz: np.ndarray
    ubz: np.ndarray
    lbg: np.ndarray
    ubg: np.ndarray
    parts: ca.Function
    margins: ca.Function
    src: np.ndarray
    orig: np.ndarray
    source_rows: np.ndarray
    N: int
    nx: list
    nu: list
    ng: list
    info: dict = field(default_factory=dict)
    #: source variables -> the running sums' values (rows over every step, :func:`_running_sums`), or None
    extra: ca.Function | None = None
    #: no Kalman box on this form (NLPProblem.has_kalman_box): the source's
    #: lifted factors sit elsewhere here, and fatrop takes no runaway stop
    has_kalman_box = False

    @property
    def formulation(self) -> str:
        return self.source.formulation

    @property
    def n_collision(self) -> int:
        return self.source.n_collision

    @property
    def anchor(self) -> Callable[[Layout], np.ndarray]:
        return self.source.anchor

    @property
    def model(self):
        return self.source.model

    def for_model(self, model) -> "OCPProblem":
        """This form over ``source.for_model(model)`` (:meth:`.NLPProblem.for_model`)."""
        return self if model is self.source.model else dataclasses.replace(self, source=self.source.for_model(model))

    def margin_values(self, zv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(collision, target) margins at z values (stage order), with the model's start belief."""
        return self.source.margin_values(self.to_source(zv))

    def pack(self, lay: Layout) -> np.ndarray:
        """Layout -> variable values in stage order (copies equal their originals,
        running sums their sums)."""
        return self._extended(self.source.pack(lay))[self.src]

    def _extended(self, zv: np.ndarray) -> np.ndarray:
        """The source's variable values followed by the running sums at them."""
        return zv if self.extra is None else np.concatenate([zv, np.asarray(self.extra(zv), float).ravel()])

    def unpack(self, zv: np.ndarray) -> Layout:
        """Variable values in stage order -> Layout (read from the originals)."""
        return self.source.unpack(np.asarray(zv, float).ravel()[self.orig])

    def to_source(self, zv: np.ndarray) -> np.ndarray:
        """Variable values here -> the source NLP's variable values."""
        return np.asarray(zv, float).ravel()[self.orig]

    def source_g(self, gv: np.ndarray) -> np.ndarray:
        """Constraint values here -> the source NLP's rows, in its order."""
        return np.asarray(gv, float).ravel()[self.source_rows]

    def without_sensing(self, lay: Layout, floor: float, slack: float = 0.1) -> tuple[np.ndarray, np.ndarray,
                                                                                    np.ndarray]:
        """:meth:`.NLPProblem.without_sensing` in stage order; a copy stays
        free (its gap row ties it to the fixed original)."""
        z0, lb, ub = self.source.without_sensing(lay, floor, slack)
        return self._extended(z0)[self.src], self._bounds(lb, -np.inf), self._bounds(ub, np.inf)

    def _bounds(self, b: np.ndarray, free: float) -> np.ndarray:
        out = np.full(self.src.size, free)
        out[self.orig] = b
        return out


#: build_nlp's variable blocks (symbol names) and the step of their first column
_LAYOUT = {"x": 1, "s": 1, "m": 2, "lam": 1}


def stage_labels(nlp: NLPProblem) -> np.ndarray:
    """Step (1..K) of every variable of ``nlp``, -1 where the layout does not
    say: ``info["stages"]`` when the NLP supplies it, else by symbol name
    from build_nlp's layout (x_k, L_k, M_k for k >= 2, lam_k, each block
    column by column, one column per step)."""
    n = int(nlp.z.shape[0])
    if "stages" in nlp.info:
        lab = np.asarray(nlp.info["stages"], int).ravel()
        if lab.size != n:
            raise ValidationError("stages", f"needs one label per NLP variable ({n}), got {lab.size}")
        return lab
    K = int(nlp.info["K"])
    base = np.array([nlp.z[i].name().rsplit("_", 1)[0] for i in range(n)])
    lab = np.full(n, -1)
    for name, first in _LAYOUT.items():
        idx = np.flatnonzero(base == name)
        steps = K - first + 1
        if idx.size and steps > 0 and idx.size % steps == 0:
            lab[idx] = first + np.arange(idx.size) // (idx.size // steps)
    return lab


def additive_terms(expr: ca.SX, z: ca.SX | None = None, divisions: bool = False) -> list[ca.SX]:
    """Scalar ``expr`` as a list of terms whose sum it is: the tree of sums,
    differences, negations and products with a constant (``divisions``: and
    divisions by one) is opened; every
    other node is one term (with its sign and constant factor). With ``z``,
    a product with a factor free of ``z`` (a parameter such as alpha) is
    opened too, the factor kept on each term."""

    def factor(e: ca.SX):
        if e.is_constant():
            return float(e)
        return e if z is not None and not ca.depends_on(e, z) else None

    out: list[ca.SX] = []
    stack = [(expr, 1.0)]
    while stack:
        e, c = stack.pop()
        if e.is_op(ca.OP_ADD):
            stack += [(e.dep(0), c), (e.dep(1), c)]
        elif e.is_op(ca.OP_SUB):
            stack += [(e.dep(0), c), (e.dep(1), -c)]
        elif e.is_op(ca.OP_NEG):
            stack.append((e.dep(0), -c))
        elif e.is_op(ca.OP_MUL) and factor(e.dep(0)) is not None:
            stack.append((e.dep(1), c * factor(e.dep(0))))
        elif e.is_op(ca.OP_MUL) and factor(e.dep(1)) is not None:
            stack.append((e.dep(0), c * factor(e.dep(1))))
        elif divisions and e.is_op(ca.OP_DIV) and e.dep(1).is_constant():
            stack.append((e.dep(0), c / float(e.dep(1))))
        elif e.is_constant() and float(e) == 0.0:
            continue
        else:
            out.append(c * e)
    return out


def _deps(exprs: ca.SX, z: ca.SX) -> list[np.ndarray]:
    """For each entry of ``exprs``, the indices of the variables it reads."""
    sp = ca.jacobian_sparsity(exprs, z).T        # column i: entry i's variables
    colind, row = np.asarray(sp.colind()), np.asarray(sp.row())
    return [row[colind[i]:colind[i + 1]] for i in range(exprs.shape[0])]


def _running_sums(g: ca.SX, z: ca.SX, p: ca.SX, wide: list[int], K: int,
                  stage: Callable[[np.ndarray, str], int]) -> tuple[ca.SX, ca.SX, list[ca.SX], np.ndarray, ca.SX]:
    """Rows that read more than two steps, as running sums (the budget row
    sum_kj g(tau_kj) <= Delta): row i = sum of additive terms, each reading
    one step or two neighbours, becomes variables r_1..r_K with rows
    r_k - r_{k-1} - (the terms of step k) = 0, and row i itself becomes r_K
    with its bounds. Returns (the new variables, the rows with row i
    replaced, the new equality rows, the new variables' steps, their values
    as expressions of z)."""
    new_z, new_rows, new_lab, values = [], [], [], []
    rows = [g[i] for i in range(int(g.shape[0]))]
    for i in wide:
        terms = additive_terms(g[i], z, divisions=True)
        if any(ca.depends_on(t, p) for t in terms):
            raise ValidationError("formulation", f"row {i} reads every step and a parameter; a stage form "
                                                 "needs neighbours only")
        at = [max(stage(d, f"a term of row {i}"), 1) for d in _deps(ca.vertcat(*terms), z)]
        r = ca.SX.sym(f"sum{i}", K)
        total = ca.SX(0)
        for k in range(1, K + 1):
            step = sum((t for t, s in zip(terms, at) if s == k), ca.SX(0))
            new_rows.append(r[k - 1] - (r[k - 2] if k > 1 else 0) - step)
            total = total + step
            values.append(total)
        rows[i] = r[K - 1]
        new_z.append(r)
        new_lab.append(np.arange(1, K + 1))
    return ca.vertcat(*new_z), ca.vertcat(*rows), new_rows, np.concatenate(new_lab), ca.vertcat(*values)


def build_ocp(nlp: NLPProblem) -> OCPProblem:
    """``nlp`` in stage order (module doc); the same optimum, variable for variable."""
    z = nlp.z
    n = int(z.shape[0])
    m = int(nlp.g.shape[0])
    K = int(nlp.info["K"])
    lab = stage_labels(nlp)
    terms = additive_terms(nlp.f, z)
    T = ca.vertcat(*terms) if terms else ca.SX(0, 1)
    row_deps = _deps(nlp.g, z)
    term_deps = _deps(T, z)

    def _span(deps: np.ndarray) -> int:
        known = lab[deps][lab[deps] > 0]
        return int(known.max() - known.min()) if known.size else 0

    def _stage(deps: np.ndarray, what: str) -> int:
        known = lab[deps][lab[deps] > 0]
        if known.size == 0:
            return 0
        hi, lo = int(known.max()), int(known.min())
        if hi - lo > 1:
            raise ValidationError("formulation", f"{nlp.formulation!r}: {what} reads steps {lo}..{hi}; "
                                                 "a stage form needs neighbours only")
        return hi

    # rows over the whole path (a risk budget's) become running sums below; they place nothing
    wide = [i for i, d in enumerate(row_deps) if _span(d) > 1]
    # unlabelled variables: the largest step of what reads them
    if np.any(lab < 0):
        lab = lab.copy()
        lab_new = np.zeros(n, int)
        skip = set(wide)
        narrow = [d for i, d in enumerate(row_deps) if i not in skip]
        for deps, what in [(d, "a row") for d in narrow] + [(d, "a cost term") for d in term_deps]:
            s = _stage(deps, what)
            free = deps[lab[deps] < 0]
            lab_new[free] = np.maximum(lab_new[free], s)
        if np.any((lab < 0) & (lab_new < 1)):
            raise ValidationError("stages", "some NLP variables have no step label and nothing places them")
        lab = np.where(lab < 0, lab_new, lab)
        wide = [i for i, d in enumerate(row_deps) if _span(d) > 1]     # a budget row reads only levels

    g, g_lo, g_hi, z_lo, z_hi, extra = nlp.g, nlp.lbg, nlp.ubg, nlp.lbz, nlp.ubz, None
    if wide:
        r, g, sums, r_lab, values = _running_sums(nlp.g, z, nlp.p, wide, K, _stage)
        extra = ca.Function("running_sums", [z], [values])     # their values at a source point (pack)
        z = ca.vertcat(z, r)
        g = ca.vertcat(g, *sums)
        lab = np.concatenate([lab, r_lab])
        g_lo = np.concatenate([g_lo, np.zeros(len(sums))])
        g_hi = np.concatenate([g_hi, np.zeros(len(sums))])
        z_lo = np.concatenate([z_lo, np.full(r.shape[0], -np.inf)])
        z_hi = np.concatenate([z_hi, np.full(r.shape[0], np.inf)])
        row_deps = _deps(g, z)
    n_all = int(z.shape[0])

    row_stage = np.array([max(_stage(d, "a row"), 1) for d in row_deps], int)
    term_stage = np.array([max(_stage(d, "a cost term"), 1) for d in term_deps], int)

    # carried variables of step k - 1, read by stage k's rows or terms
    carried: list[np.ndarray] = [np.zeros(0, int)] * (K + 2)
    for k in range(2, K + 1):
        used = [d for d, s in zip(row_deps, row_stage) if s == k] + [d for d, s in zip(term_deps, term_stage) if s == k]
        allv = np.unique(np.concatenate(used)) if used else np.zeros(0, int)
        carried[k] = allv[lab[allv] == k - 1]

    zs = [z[i] for i in range(n_all)]
    vars_o, src, lbz, ubz, gs, lbg, ubg, rows_src = [], [], [], [], [], [], [], []
    nx, nu, ng = [], [], []
    f_parts = []
    copies: list[ca.SX] = [ca.SX(0, 1)] * (K + 2)
    for k in range(1, K + 1):
        c = carried[k]
        copies[k] = ca.SX.sym(f"carry{k}", c.size) if c.size else ca.SX(0, 1)
        own = np.flatnonzero(lab == k)
        vars_o += [copies[k][j] for j in range(c.size)] + [zs[i] for i in own]
        src += list(c) + list(own)
        lbz += [-np.inf] * c.size + list(z_lo[own])
        ubz += [np.inf] * c.size + list(z_hi[own])
        nx.append(int(c.size))
        nu.append(int(own.size))
    for k in range(1, K + 1):
        # gap rows to stage k + 1: copy - original = 0 (identity on the copy)
        if k < K:
            c = carried[k + 1]
            for j, i in enumerate(c):
                gs.append(copies[k + 1][j] - zs[i])
                lbg.append(0.0)
                ubg.append(0.0)
                rows_src.append(-1)
        rows = np.flatnonzero(row_stage == k)
        tms = np.flatnonzero(term_stage == k)
        old = ca.vertcat(*[zs[i] for i in carried[k]]) if carried[k].size else ca.SX(0, 1)
        ex = [g[rows.tolist()] if rows.size else ca.SX(0, 1), T[tms.tolist()] if tms.size else ca.SX(0, 1)]
        if carried[k].size:
            ex = ca.substitute(ex, [old], [copies[k]])
        gs += [ex[0][j] for j in range(rows.size)]
        lbg += list(g_lo[rows])
        ubg += list(g_hi[rows])
        rows_src += [int(r_) if r_ < m else -1 for r_ in rows]     # running sums: no source row
        if tms.size:
            f_parts.append(ca.sum1(ex[1]))
        ng.append(int(rows.size))
    z_o = ca.vertcat(*vars_o)
    g_o = ca.vertcat(*gs) if gs else ca.SX(0, 1)
    f_o = sum(f_parts, ca.SX(0)) if f_parts else ca.SX(0)
    src = np.asarray(src, int)
    is_copy = np.zeros(src.size, bool)
    pos = 0
    for k in range(1, K + 1):
        is_copy[pos:pos + nx[k - 1]] = True
        pos += nx[k - 1] + nu[k - 1]
    orig = np.empty(n_all, int)
    orig[src[~is_copy]] = np.flatnonzero(~is_copy)
    orig = orig[:n]                                          # the source's variables (not the running sums)
    rows_src = np.asarray(rows_src, int)
    source_rows = np.empty(int(nlp.g.shape[0]), int)
    source_rows[rows_src[rows_src >= 0]] = np.flatnonzero(rows_src >= 0)

    z_src = ca.vertcat(*[z_o[int(i)] for i in orig])           # the source variables, read from the originals
    parts = ca.Function("ocp_parts", [z_o, nlp.p], nlp.parts(z_src, nlp.p), ["z", "p"],
                        ["control", "information", "regulariser"])
    start = ca.SX.sym("start", nlp.margins.size1_in(1))
    margins = ca.Function("ocp_margins", [z_o, start], nlp.margins(z_src, start), ["z", "start"],
                          ["collision", "target"])
    # "m_offset" places the source's lifted factors, not this form's (no Kalman box here)
    info = {**{k: v for k, v in nlp.info.items() if k != "m_offset"}, "n_variables": int(z_o.shape[0]),
            "n_constraints": int(g_o.shape[0]), "n_carried": int(sum(nx)), "stages_of_source": lab[:n],
            "n_running_sums": n_all - n}
    return OCPProblem(nlp, z_o, nlp.p, f_o, g_o, np.asarray(lbz, float), np.asarray(ubz, float),
                      np.asarray(lbg, float), np.asarray(ubg, float), parts, margins, src, orig, source_rows,
                      K - 1, nx, nu, ng, info, extra)
