"""Certificate warm start: the lambda of every stage and hazard from a reference path.

An MPC that carries Theorem-1 certificates as decision variables starts
feasible only if its first guess holds certificates that prove the guessed
transitions clear. :func:`certificate_warm_start` computes them for any
reference :class:`~belief_nlp.BeliefPath` (a plan, a warm start, a smoothed
path, a previous closed loop) with the smoother's own routine
(:func:`belief_nlp.smoother.warmstart.certificates`: the exact common
certificate of each transition, shrunk toward zero while a comfortable slack
remains), laid out as a bundle's ``lam`` input and in its units.
"""

from __future__ import annotations

import numpy as np

from ..errors import InfeasibleStartError
from ..path import BeliefPath
from ..scenario import Scenario
from .bundle import SafetyBundle, _scenario, stage_bundle

__all__ = ["certificate_warm_start"]


def certificate_warm_start(scenario: Scenario | str, path: BeliefPath, bundle: SafetyBundle | None = None,
                           check: bool = True, hazards=None, levels: np.ndarray | None = None) -> np.ndarray:
    """Certificates (K, J F) for every transition of ``path``, in ``bundle``'s units.

    Row k is the ``lam`` input of ``bundle`` for the transition k -> k+1
    (hazard-major, padded faces zero). ``bundle`` defaults to the SI stage
    bundle of ``scenario``. With ``check`` (default) every row of the bundle
    is evaluated at the path and the certificates, and
    :class:`~belief_nlp.errors.InfeasibleStartError` names the first
    transition and hazard that violate its bound -- a path that is not itself
    clear has no certificate (Theorem 1 is exact); make it clear first with
    :func:`belief_nlp.warm_start` (it adds sensing). ``hazards``: the
    scenario's :class:`~belief_nlp.geometry.PolytopeSet`, if already built
    (a closed loop calls this every step; building it costs ~30 ms).
    ``levels`` (K, J): each transition's level per hazard (a risk
    allocation; default the scenario's chi2), for the certificates and the check.
    """
    from ..smoother.warmstart import certificates

    sc = _scenario(scenario)
    bundle = stage_bundle(sc) if bundle is None else bundle
    lv = None if levels is None else np.asarray(levels, float)
    lam_si = certificates(sc, path, hazards, chi2=lv)          # (K, J, F_model), SI
    K, J, F = lam_si.shape
    out = np.zeros((K, bundle.J, bundle.F))
    out[:, :J, :F] = lam_si
    out = out.reshape(K, -1) * bundle.factors["lam"]
    if check:
        f = bundle.factors
        Wk = path.transition_noise
        for k in range(K):
            res = bundle(path.x[k] * f["x"], path.P[k] * f["P"], path.x[k + 1] * f["x"], Wk[k] * f["W"], out[k],
                         # rows >= margin at level lv - margin: the certificate proves lv itself
                         p=None if lv is None else bundle.params(levels=lv[k] - bundle.margin),
                         slack=np.zeros(bundle.n_slack) if bundle.n_slack else None)
            g = np.asarray(res[0] if bundle.n_slack else res).ravel()
            bad = np.flatnonzero(g < bundle.lbg - 1e-12 * (1 + np.abs(bundle.lbg)))
            if bad.size:
                raise InfeasibleStartError(f"transition {k + 1}: row {bundle.names[bad[0]]} = {g[bad[0]]:.3g} "
                                           f"< {bundle.lbg[bad[0]]:.3g}; the reference path is not clear there")
    return out
