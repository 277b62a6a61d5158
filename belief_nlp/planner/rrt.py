"""IG-RRT*: RRT* in Gaussian belief space (Pedram & Tanaka), with exact safety.

Nodes are beliefs (x, P). One iteration (one new node):

1. **Sample** (x_s, P_s) (see :class:`~.sampling.BeliefSampler`).
2. **Nearest** live node in the edge cost, with the authors' matrix minimum
   standing in for P_s when the step is not lossless (vectorised over nodes).
3. **Steer**: when the nearest is farther than the rewiring radius r, move the
   sample to the fraction r / D of the way from it (x and P interpolated).
4. **Shrink** P until its confidence ellipse clears every obstacle and wall.
   The authors halve P and re-check; one exact distance gives the number of
   halvings directly. A mean inside a hazard rejects the sample.
5. **Parent**: candidates are live nodes with a lossless edge of cost <= r.
   They are examined in order of cost-to-come through them and the first
   collision-free one is the parent, i.e. exactly the cheapest
   collision-free candidate while checking only as many edges as needed.
6. **Rewire**: live neighbours v with a lossless edge q -> v of cost <= r
   that would lower v's cost; the cost change propagates to v's subtree.
7. **Goal**: the node is a goal when its ellipse lies inside the target.
8. **Branch-and-bound** (as the authors, after Karaman et al.'s anytime
   RRT*): drop nodes whose cost-to-come plus an admissible, consistent
   cost-to-go bound h exceeds the best cost. Consistency means a kept node's
   ancestors are kept, and the best path is never touched; a dropped node
   comes back if a rewired ancestor makes it promising again. Dropped nodes
   leave the nearest, parent and rewiring searches, so later samples are
   steered toward the part of the tree that can still improve the best path.
   That is a change of the search, not only a saving: before the first
   solution the runs with and without it are identical, after it they
   differ (on ``quad`` pruning lowers the median best cost at N = 2000 from
   2.08 to 1.68 in the authors' unit; see benchmarks/bench_planner.py).

Edge collision decisions are exact in continuous time (paper Theorem 1; see
:mod:`.collision`), never sampled, and the edges of one iteration (all
parent candidates, in order, and all rewiring candidates) go to the checker
in one batch; it decides the parents only up to the first clear one. Step 1-4 samples that get no node do not count
as nodes (as the authors' loop); they count as attempts.

The radius follows the authors: r_n = min(max_radius, gamma (log n / n)^(1/d))
with n the number of live nodes plus one.

Steps 1-7 run in numpy (:mod:`.iteration`, the reference) or, in 2-D with
numba installed, compiled (:mod:`.compiled`): ``PlannerOptions.backend``.
"""

from __future__ import annotations

import logging
import math
import os
import time
from typing import Any

import numpy as np

from .. import belief
from ..errors import ValidationError
from ..path import BeliefPath
from ..scenario import Scenario, load_scenario
from .collision import CollisionChecker
from .compiled import resolve_backend
from .iteration import _REL_EPS, IterationMixin
from .metrics import EdgeMetric
from .options import PlannerOptions, default_gamma, resolve_options
from .result import PlanResult, TreeView
from .sampling import BeliefSampler
from .tree import BeliefTree

__all__ = ["IGRRTStar"]

log = logging.getLogger("belief_nlp.planner")



def _polytope_volume(poly) -> float:
    from scipy.spatial import ConvexHull

    return float(ConvexHull(poly.vertices).volume)


class IGRRTStar(IterationMixin):
    """The IG-RRT* planner for one scenario and one set of options.

    Call :meth:`plan` to run; the tree of the last run stays available as
    ``tree_`` (a :class:`~belief_nlp.planner.tree.BeliefTree`).
    :func:`belief_nlp.plan` is the one-call form.

    Parameters
    ----------
    scenario : Scenario or str
        The planning problem, or a built-in name / scenario file.
    **options
        Any field of :class:`~belief_nlp.planner.options.PlannerOptions`
        (``n_nodes``, ``seed``, ``alpha``, ``metric``, ``noise``,
        ``max_radius``, ...); defaults come from the scenario's ``[planner]``
        table, then the built-in defaults.

    Raises
    ------
    ValidationError
        For an unknown option or an invalid value, naming it.
    """

    def __init__(self, scenario: Scenario | str, **options: Any):
        if isinstance(scenario, (str, os.PathLike)):
            scenario = load_scenario(scenario)
        if not isinstance(scenario, Scenario):
            raise ValidationError("scenario", f"must be a Scenario, got {type(scenario).__name__}")
        self.scenario = scenario
        self.options: PlannerOptions = resolve_options(scenario.planner, scenario.alpha, scenario.chi2, **options)
        o = self.options
        sc = scenario
        self.dim = sc.dim
        self.per_metre = o.noise == "per_metre"
        self.W_edge = sc.W_rate if self.per_metre else sc.W
        self.metric = EdgeMetric(o.metric, o.alpha, o.info_unit, self.W_edge)
        # 2-D: edge costs from entries (closed form); (W11, W12, W22) as a column
        self._entries = self.dim == 2 and self.metric.entries_ok
        We = self.W_edge
        self._W_entries = np.array([[We[0, 0]], [We[0, 1]], [We[1, 1]]]) if self.dim == 2 else None
        self._W_list = self._W_entries.ravel().tolist() if self.dim == 2 else None
        self._W4 = We.ravel().tolist()
        self.gamma = o.gamma if o.gamma is not None else default_gamma(self.dim, _polytope_volume(sc.domain))
        # Cost-to-go bound for branch-and-bound, h(x, P) = dist_lb(x) + weight * info_lb(P):
        # dist_lb = largest violated target face (a lower bound of the Euclidean
        # distance to the target, 1-Lipschitz); for the entropy metric,
        # info_lb = max(0, 1/2 (log det P - log det P_max)) where P_max bounds the
        # covariance of any ellipse inside the target by volume. Along any lossless
        # path the information is >= 1/2 (log det P_start - log det P_end) (the
        # prediction only adds noise), so h is admissible and consistent.
        self._tA, self._tb = sc.target.A, sc.target.b
        zeta = math.pi ** (self.dim / 2) / math.gamma(self.dim / 2 + 1)
        self._logdet_max = 2.0 * math.log(_polytope_volume(sc.target) / zeta) - self.dim * math.log(sc.chi2)
        self.tree_: BeliefTree | None = None
        # "numpy" or "numba" (ValidationError for numba when it cannot run here)
        self.backend = resolve_backend(o.backend, self.dim, o.metric)

    # ------------------------------------------------------------------- plan
    def plan(self) -> PlanResult:
        """Grow the tree until the node budget, the time limit or convergence;
        return the best verified path (see :class:`~.result.PlanResult`)."""
        o = self.options
        sc = self.scenario
        t_start = time.perf_counter()
        cpu_start = time.process_time()
        rng = np.random.default_rng(o.seed)
        sampler = BeliefSampler(sc, o.eig_range, o.eig_ratio, o.goal_bias)
        samples = sampler.stream(rng)
        checker = CollisionChecker(sc, o.safety_margin, o.collision_chi2)
        tree = BeliefTree(self.dim, capacity=min(o.n_nodes, 4096))
        self.tree_ = tree
        root_logdet = _safe_logdet(sc.P0)
        tree.add(sc.x0, sc.P0, -1, 0.0, 0.0, self._h(sc.x0, root_logdet), goal=False)
        # (The root is never a goal: a path needs at least one transition.)

        max_attempts = o.max_attempts if o.max_attempts is not None else 200 * o.n_nodes + 1000
        stats: dict[str, Any] = {"attempts": 0, "rejected_in_hazard": 0, "rejected_too_small": 0,
                                 "rejected_no_candidate": 0, "rejected_all_colliding": 0,
                                 "parent_candidates": 0, "rewire_candidates": 0, "rewires": 0,
                                 "pruned": 0, "revived": 0, "hopeless_nodes": 0, "goal_nodes": 0}
        timings = {"sample": 0.0, "candidates": 0.0, "collision": 0.0, "rewire": 0.0, "prune": 0.0}
        self._stats, self._timings = stats, timings
        step = self._iterate
        compiled = None
        if self.backend == "numba":
            from .compiled import COLD_NOTE, cache_is_warm
            from .compiled.driver import CompiledAttempt      # drops a stale cache first

            if not cache_is_warm():
                log.info(COLD_NOTE)

            compiled = CompiledAttempt(self, checker)
            step = compiled.iterate
            # compile (or load) before the clock: the time limit and the anytime trace count planning only
            probe = sampler.stream(np.random.default_rng(0)).next()     # a sample of the run's types, its rng apart
            c0 = time.process_time()
            timings["compile"] = compiled.warm_up(tree, probe[:2])
            t_start += timings["compile"]                  # "total" and "cpu" below are the planning's own
            cpu_start += time.process_time() - c0
        history: list[float] = [math.inf]
        trace: list[list[float]] = []           # [[seconds, best cost]] at each improvement
        best, best_node = math.inf, -1
        first_solution: int | None = None
        stop_reason = "node budget reached"

        progress = None
        if o.progress:
            from .._progress import progress_bar

            progress = progress_bar(o.n_nodes, "IG-RRT*", "node")
            progress.update(1)
        log.info("IG-RRT* on %r: n_nodes=%d seed=%s metric=%s noise=%s alpha=%g", sc.name, o.n_nodes, o.seed,
                 o.metric, o.noise, o.alpha)
        try:
            while tree.n < o.n_nodes:
                if o.time_limit is not None and time.perf_counter() - t_start > o.time_limit:
                    stop_reason = f"time limit of {o.time_limit:g} s reached"
                    break
                if stats["attempts"] >= max_attempts:
                    stop_reason = f"attempt limit of {max_attempts} reached"
                    break
                stats["attempts"] += 1
                rewires = stats["rewires"]
                q = step(samples, checker, tree, best)
                if q is None:
                    continue
                # best cost: a new goal node, or costs of goal nodes dropped by
                # rewiring (nothing else changes the costs or the live goals)
                improved = False
                goals = ((tree.goal[: tree.n] & tree.live[: tree.n]).nonzero()[0]
                         if tree.goal[q] or stats["rewires"] != rewires else ())
                if len(goals):
                    j = int(tree.cost[goals].argmin())
                    if tree.cost[goals[j]] < best:
                        best, best_node = float(tree.cost[goals[j]]), int(goals[j])
                        if first_solution is None:
                            first_solution = tree.n
                            log.info("first solution at node %d: cost %.6g", tree.n, best)
                        else:
                            log.debug("node %d: best cost %.6g", tree.n, best)
                        improved = True
                        trace.append([time.perf_counter() - t_start, best])
                # Pruning between improvements would drop nothing: with best fixed,
                # costs only fall (rewiring), a node that arrives above the bound
                # is dropped at once (hopeless) and a revived one is below it.
                # So the pass runs when best improves (``prune_every`` >= 1
                # gives the same tree).
                if improved and o.branch_and_bound:
                    self._prune(tree, best, best_node)
                history.append(best)
                if progress is not None:
                    progress.update(1)
                    if math.isfinite(best):
                        progress.set_postfix(best=f"{best:.4g}", refresh=False)
                w = o.convergence_window
                if (o.convergence_tol is not None and math.isfinite(best) and len(history) > w
                        and history[-1 - w] - best <= o.convergence_tol * abs(best)):
                    stop_reason = (f"converged: best cost improved by <= {o.convergence_tol:g} (relative) "
                                   f"over the last {w} nodes")
                    break
        finally:
            if progress is not None:
                progress.close()

        if compiled is not None:
            compiled.flush(stats, checker.stats)
        stats["backend"] = self.backend
        stats.update({"nodes": tree.n, "live_nodes": int(np.count_nonzero(tree.live[: tree.n])),
                      "goal_nodes": int(np.count_nonzero(tree.goal[: tree.n]))})
        stats.update({f"collision_{k}": v for k, v in checker.stats.items()})
        # The counts the issue names, under plain names.
        stats["edges_checked"] = checker.stats["edges"]
        stats["collision_checks"] = checker.stats["pairs_exact"]
        stats["undecided_pairs"] = checker.stats["undecided_pairs"]
        timings["tree"] = time.perf_counter() - t_start
        return self._finish(tree, best_node, np.asarray(history), first_solution, stop_reason, stats, timings,
                            t_start, cpu_start, trace)

    # ------------------------------------------------------ branch-and-bound
    def _prune(self, tree: BeliefTree, best: float, best_node: int) -> None:
        if not self.options.branch_and_bound:
            return
        t0 = time.perf_counter()
        n = tree.n
        live = tree.live[:n]
        kill = live & (tree.cost[:n] + tree.h[:n] > best * (1 + _REL_EPS))
        kill[0] = False
        if best_node >= 0:
            kill[best_node] = False
        cnt = int(np.count_nonzero(kill))
        if cnt:
            tree.set_live(kill.nonzero()[0], False)
            self._stats["pruned"] += cnt
        self._timings["prune"] += time.perf_counter() - t0

    # ----------------------------------------------------------------- finish
    def _finish(self, tree: BeliefTree, best_node: int, history: np.ndarray, first_solution: int | None,
                stop_reason: str, stats: dict, timings: dict, t_start: float, cpu_start: float,
                trace: list) -> PlanResult:
        from ..verify import verify

        o = self.options
        sc = self.scenario
        n = tree.n
        view = TreeView(tree.x[:n].copy(), tree.P[:n].copy(), tree.parent[:n].copy(), tree.cost[:n].copy(),
                        tree.live[:n].copy(), tree.goal[:n].copy())
        common = dict(alpha=o.alpha, metric=o.metric, info_unit=o.info_unit, noise=o.noise,
                      cost_history=history, first_solution_iteration=first_solution, tree=view, stats=stats,
                      timings=timings, options=o.to_dict(), seed=o.seed, scenario=sc.name, cost_trace=trace)
        t0 = time.perf_counter()
        path = None
        report = None
        message = ""
        if best_node < 0:
            message = (f"no path to the target found with {n} nodes in {stats['attempts']} attempts "
                       f"({stop_reason})")
        else:
            # Verify the best path; should it ever fail, fall back to the next goal nodes.
            goals = np.flatnonzero(tree.goal[:n] & tree.live[:n])
            goals = goals[np.argsort(tree.cost[goals], kind="stable")]
            if best_node not in goals:
                goals = np.concatenate([[best_node], goals])
            failures = []
            for g in goals[:5]:
                cand_path = self._belief_path(tree, int(g))
                rep = verify(sc, cand_path)
                if rep.safe:
                    path, report, best_node = cand_path, rep, int(g)
                    break
                failures.append(rep.summary().splitlines()[0])
                log.warning("planned path to node %d failed verification: %s", g, rep.summary())
            if path is None:
                message = "paths were found but none passed verification: " + "; ".join(failures)
            else:
                message = f"path found ({stop_reason})"
                if failures:
                    message += f"; {len(failures)} cheaper path(s) failed verification"
        timings["verify"] = time.perf_counter() - t0
        timings["total"] = time.perf_counter() - t_start
        timings["cpu"] = time.process_time() - cpu_start
        if path is None:
            log.info("IG-RRT* failed: %s", message)
            return PlanResult(success=False, message=message, path=None, cost=math.inf, travel=math.nan,
                              information=math.nan, verification=None, **common)
        nodes = tree.path_to(best_node)
        travel = path.length
        information = float(np.sum(tree.edge_info[nodes[1:]])) * self.metric.unit_factor
        cost = float(tree.cost[best_node])
        log.info("IG-RRT* done: cost %.6g with %d nodes in %.3g s", cost, n, timings["total"])
        return PlanResult(success=True, message=message, path=path, cost=cost, travel=travel,
                          information=information, verification=report.to_dict(), **common)

    def _belief_path(self, tree: BeliefTree, goal_node: int) -> BeliefPath:
        o = self.options
        sc = self.scenario
        nodes = tree.path_to(goal_node)
        meta = {"planner": "IG-RRT*", "scenario": sc.name, "seed": o.seed, "options": o.to_dict(),
                "cost": float(tree.cost[goal_node]), "metric": o.metric, "info_unit": o.info_unit,
                "nodes": [int(v) for v in nodes]}
        return BeliefPath.from_covariances(tree.x[nodes], tree.P[nodes], W=sc.W, W_rate=sc.W_rate,
                                           noise=o.noise, meta=meta)


def _safe_logdet(P: np.ndarray) -> float:
    try:
        return float(belief.logdet(P))
    except np.linalg.LinAlgError:
        return -math.inf
