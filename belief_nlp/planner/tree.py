"""Node storage of the IG-RRT* tree: preallocated numpy arrays grown by doubling."""

from __future__ import annotations

import numpy as np

from .kernels import chol_lower, inv_lower

__all__ = ["BeliefTree", "LiveView"]


class LiveView:
    """The live nodes, gathered once per change of the tree.

    ``idx`` their indices, ``x`` their means (``xc`` (2, n): the same as
    contiguous coordinate rows, 2-D only, else None); ``pe`` (3, n) the entries
    (P11, P12, P22) of their covariances (2-D only, else None), contiguous
    per entry for the closed-form kernels; ``P`` (n, d, d) their covariances,
    gathered on first use (the 2-D planner reads entries only). ``extra`` is
    a scratch dict for quantities derived from them, which share their
    lifetime (the planner keeps the prior's entries there).
    """

    __slots__ = ("idx", "x", "xc", "pe", "extra", "_P_all")

    def __init__(self, idx: np.ndarray, x: np.ndarray, P_all: np.ndarray, pe: np.ndarray | None):
        self.idx, self.x, self.pe, self._P_all = idx, x, pe, P_all
        self.xc = np.ascontiguousarray(x.T) if x.shape[1] == 2 else None
        self.extra: dict = {}

    @property
    def P(self) -> np.ndarray:
        P = self.extra.get("P")
        if P is None:
            P = self.extra["P"] = self._P_all[self.idx]
        return P


class BeliefTree:
    """Beliefs (x, P) with parent pointers, costs and per-node factor caches.

    Arrays are sized ``capacity`` and doubled when full; the first ``n`` rows
    are valid. ``children`` is a list of Python lists (rewiring moves one
    child at a time, and subtrees are small, so lists beat array scans).

    Per node: mean ``x``, covariance ``P``, its Cholesky factor ``L`` and
    ``Linv`` = L^-1 (for the rewiring kernels), ``parent`` (-1 for the root),
    ``cost`` (cost-to-come), ``edge_info`` (metric value of the edge from the
    parent), ``h`` (admissible cost-to-go bound for branch-and-bound),
    ``live`` (False once pruned) and ``goal`` (ellipse inside the target).
    In 2-D, ``pe`` and ``le`` (3, capacity) repeat the entries (P11, P12, P22)
    of P and (L^-1_11, L^-1_21, L^-1_22) of Linv, one contiguous row per
    entry, which is what the closed-form kernels of :mod:`.kernels` read.
    """

    def __init__(self, dim: int, capacity: int = 256):
        self.dim = dim
        self.n = 0
        cap = max(int(capacity), 2)
        d = dim
        self.x = np.zeros((cap, d))
        self.P = np.zeros((cap, d, d))
        self.L = np.zeros((cap, d, d))
        self.Linv = np.zeros((cap, d, d))
        self.parent = np.full(cap, -1, dtype=np.int64)
        self.cost = np.full(cap, np.inf)
        self.edge_info = np.zeros(cap)
        self.h = np.zeros(cap)
        self.live = np.zeros(cap, dtype=bool)
        self.goal = np.zeros(cap, dtype=bool)
        self.pe = np.zeros((3, cap)) if d == 2 else None
        self.le = np.zeros((3, cap)) if d == 2 else None
        self.children: list[list[int]] = []
        self._live_cache: LiveView | None = None   # dropped on any change

    def live_arrays(self) -> LiveView:
        """The live nodes (:class:`LiveView`); cached until the tree changes
        (rejected samples leave it unchanged, so the gather is reused)."""
        if self._live_cache is None:
            idx = self.live[: self.n].nonzero()[0]
            self._live_cache = LiveView(idx, self.x.take(idx, axis=0), self.P,
                                        None if self.pe is None else self.pe.take(idx, axis=1))
        return self._live_cache

    def set_live(self, idx, value: bool) -> None:
        """Mark nodes live (revived) or not (pruned)."""
        self.live[idx] = value
        self._live_cache = None

    _ARRAYS = ("x", "P", "L", "Linv", "parent", "cost", "edge_info", "h", "live", "goal")

    def _grow(self) -> None:
        for name in self._ARRAYS:
            arr = getattr(self, name)
            new = np.empty((2 * arr.shape[0],) + arr.shape[1:], dtype=arr.dtype)
            new[: arr.shape[0]] = arr
            setattr(self, name, new)
        if self.pe is not None:
            cap = self.pe.shape[1]
            for name in ("pe", "le"):
                new = np.zeros((3, 2 * cap))
                new[:, :cap] = getattr(self, name)
                setattr(self, name, new)

    def add(self, x: np.ndarray, P: np.ndarray, parent: int, cost: float, edge_info: float, h: float,
            goal: bool, L: np.ndarray | None = None, Linv: np.ndarray | None = None) -> int:
        """Append a node; returns its index. ``L`` is P's Cholesky factor (None: computed;
        the root may have a singular P0, then identity placeholders are stored),
        ``Linv`` its inverse (None: computed from L)."""
        if self.n == self.x.shape[0]:
            self._grow()
        i = self.n
        self.x[i] = x
        self.P[i] = P
        if L is None:
            try:
                L = chol_lower(P)
            except np.linalg.LinAlgError:
                L = np.eye(self.dim)  # singular start covariance: never a rewiring target
        self.L[i] = L
        self.Linv[i] = Li = inv_lower(L) if Linv is None else Linv
        if self.pe is not None:
            self.pe[:, i] = P[0, 0], P[0, 1], P[1, 1]
            self.le[:, i] = Li[0, 0], Li[1, 0], Li[1, 1]
        self.parent[i] = parent
        self.cost[i] = cost
        self.edge_info[i] = edge_info
        self.h[i] = h
        self.live[i] = True
        self.goal[i] = goal
        self.children.append([])
        self._live_cache = None
        if parent >= 0:
            self.children[parent].append(i)
        self.n += 1
        return i

    def subtree(self, v: int) -> list[int]:
        """v and all its descendants (breadth first)."""
        out = [v]
        k = 0
        children = self.children
        while k < len(out):
            out.extend(children[out[k]])
            k += 1
        return out

    def ancestors(self, v: int) -> set[int]:
        """Strict ancestors of v."""
        out = set()
        p = int(self.parent[v])
        while p >= 0:
            out.add(p)
            p = int(self.parent[p])
        return out

    def reparent(self, v: int, new_parent: int, new_cost: float, edge_info: float) -> list[int]:
        """Move v under ``new_parent``; shift the cost of v's whole subtree by the
        change of v's cost (edge costs between fixed beliefs do not change).
        Returns the subtree."""
        old = int(self.parent[v])
        self.children[old].remove(v)
        self.children[new_parent].append(v)
        self.parent[v] = new_parent
        self.edge_info[v] = edge_info
        delta = new_cost - self.cost[v]
        sub = self.subtree(v)
        idx = np.asarray(sub)
        self.cost[idx] += delta
        self.cost[v] = new_cost  # exact for v itself
        return sub

    def path_to(self, v: int) -> list[int]:
        """Node indices from the root to v."""
        out = [v]
        p = int(self.parent[v])
        while p >= 0:
            out.append(p)
            p = int(self.parent[p])
        return out[::-1]
