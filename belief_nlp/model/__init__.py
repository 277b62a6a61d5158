"""The one symbolic model of the smoothing problem and the solver forms made from it.

* :mod:`.terms`       every term of the DOC program, written once (CasADi)
* :mod:`.data`        scenario data and points in the model's scaled units
* :mod:`.evaluate`    :class:`BeliefModel`: cost, margins and conversions at a point
* :mod:`.doc`         the convexified program of a CCP step (symbolic)
* :mod:`.cvxpy_form`  that program as one CVXPY problem, compiled once
* :mod:`.cache`       compiled problems kept in memory and, optionally, on disk
* :mod:`.nlp_form`    the exact program as an NLP for CasADi's solvers (Cholesky factors)
"""

from .data import Layout, ProblemData
from .evaluate import BeliefModel

__all__ = ["BeliefModel", "Layout", "ProblemData"]
