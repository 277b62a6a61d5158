"""Belief paths: means, prior and posterior covariances, sensing, costs."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import belief
from .errors import ValidationError

__all__ = ["BeliefPath", "NOISE_MODELS"]

NOISE_MODELS = ("per_step", "per_metre")


@dataclass(eq=False)
class BeliefPath:
    """A discrete belief path (x_k, P_k), k = 0..K.

    Attributes
    ----------
    x : (K+1, d) means; x[0] is the start.
    P : (K+1, d, d) posterior covariances; P[0] is the start covariance P0.
    P_prior : (K+1, d, d) prior covariances P_hat_k = P_{k-1} + W_k (P_prior[0] = P0).
    S : (K+1, d, d) sensing information, P_k = (P_prior_k^-1 + S_k)^-1 (S[0] = 0).
    noise : "per_step" (W_k = W, the smoother's model) or "per_metre"
        (W_k = W_rate ||x_k - x_{k-1}||, the authors' planner).
    meta : free-form provenance (planner seed, solver, ...), JSON-serialisable.

    The noise added on transition k is ``P_prior[k] - P[k-1]``; during the
    transition the covariance grows linearly, P(s) = P[k-1] + s W_k
    (paper Definition 3).
    """

    x: np.ndarray
    P: np.ndarray
    P_prior: np.ndarray
    S: np.ndarray
    noise: str = "per_step"
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.x = np.asarray(self.x, dtype=float)
        self.P = np.asarray(self.P, dtype=float)
        self.P_prior = np.asarray(self.P_prior, dtype=float)
        self.S = np.asarray(self.S, dtype=float)
        if self.x.ndim != 2:
            raise ValidationError("path.x", f"must have shape (K+1, d), got {self.x.shape}")
        n, d = self.x.shape
        if n < 2:
            raise ValidationError("path.x", "a path needs at least two points")
        for name in ("P", "P_prior", "S"):
            arr = getattr(self, name)
            if arr.shape != (n, d, d):
                raise ValidationError(f"path.{name}", f"must have shape {(n, d, d)}, got {arr.shape}")
        for name in ("x", "P", "P_prior", "S"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValidationError(f"path.{name}", "contains NaN or infinite values")
        if self.noise not in NOISE_MODELS:
            raise ValidationError("path.noise", f"must be one of {NOISE_MODELS}, got {self.noise!r}")

    # -------------------------------------------------------------- builders
    @classmethod
    def from_sensing(cls, x, P0, S, W=None, W_rate=None, noise: str = "per_step",
                     meta: dict | None = None) -> "BeliefPath":
        """Roll the Kalman recursion forward from P0 with sensing S[1..K].

        ``S`` is (K+1, d, d) (S[0] ignored) or (K, d, d) for steps 1..K.
        Give ``W`` (per step) or ``W_rate`` (per metre) to match ``noise``.
        """
        x = np.asarray(x, dtype=float)
        n, d = x.shape
        S = np.asarray(S, dtype=float)
        if S.shape[0] == n - 1:
            S = np.concatenate([np.zeros((1, d, d)), S], axis=0)
        Wk = cls._transition_noise(x, W, W_rate, noise)
        P = np.empty((n, d, d))
        Pp = np.empty((n, d, d))
        P[0] = Pp[0] = np.asarray(P0, dtype=float)
        S = S.copy()
        S[0] = 0.0
        for k in range(1, n):
            Pp[k] = P[k - 1] + Wk[k - 1]
            P[k] = belief.update(Pp[k], S[k])
        return cls(x, P, Pp, S, noise, dict(meta or {}))

    @classmethod
    def from_covariances(cls, x, P, W=None, W_rate=None, noise: str = "per_step",
                         meta: dict | None = None) -> "BeliefPath":
        """From means and posterior covariances; priors and the lossless sensing
        S_k = P_k^-1 - P_prior_k^-1 are derived (S_k may come out indefinite
        if the path is not lossless; :func:`~belief_nlp.verify` reports it)."""
        x = np.asarray(x, dtype=float)
        P = np.asarray(P, dtype=float)
        n, d = x.shape
        Wk = cls._transition_noise(x, W, W_rate, noise)
        Pp = np.empty_like(P)
        Pp[0] = P[0]
        Pp[1:] = P[:-1] + Wk
        S = np.zeros_like(P)
        S[1:] = belief.lossless_sensing(Pp[1:], P[1:])
        return cls(x, P, Pp, S, noise, dict(meta or {}))

    @staticmethod
    def _transition_noise(x: np.ndarray, W, W_rate, noise: str) -> np.ndarray:
        n, d = x.shape
        if noise == "per_step":
            if W is None:
                raise ValidationError("W", "per_step noise needs W")
            return np.broadcast_to(np.asarray(W, dtype=float), (n - 1, d, d)).copy()
        if noise == "per_metre":
            if W_rate is None:
                raise ValidationError("W_rate", "per_metre noise needs W_rate")
            lengths = np.linalg.norm(np.diff(x, axis=0), axis=1)
            return lengths[:, None, None] * np.asarray(W_rate, dtype=float)[None]
        raise ValidationError("noise", f"must be one of {NOISE_MODELS}, got {noise!r}")

    # ------------------------------------------------------------ properties
    @property
    def K(self) -> int:
        """Number of transitions."""
        return self.x.shape[0] - 1

    @property
    def dim(self) -> int:
        return self.x.shape[1]

    @property
    def transition_noise(self) -> np.ndarray:
        """W_k = P_prior[k] - P[k-1] for k = 1..K, shape (K, d, d)."""
        return self.P_prior[1:] - self.P[:-1]

    @property
    def length(self) -> float:
        """Travelled distance sum ||x_k - x_{k-1}|| (metres)."""
        return float(np.sum(np.linalg.norm(np.diff(self.x, axis=0), axis=1)))

    @property
    def control_cost(self) -> float:
        """sum ||x_k - x_{k-1}||^2 (m^2): the smoothing paper's control cost."""
        return float(np.sum(np.diff(self.x, axis=0) ** 2))

    @property
    def information(self) -> float:
        """sum 1/2 (log det P_prior_k - log det P_k) in nats."""
        return float(np.sum(belief.information_cost(self.P_prior[1:], self.P[1:])))

    def steering_cost(self, alpha: float) -> float:
        """The smoothing paper's objective: control_cost + alpha * information."""
        return self.control_cost + alpha * self.information

    def planner_cost(self, alpha: float) -> float:
        """The planner's cost: length + alpha * information (nats)."""
        return self.length + alpha * self.information

    def cost_breakdown(self, alpha: float) -> dict[str, float]:
        return {
            "steering": self.steering_cost(alpha),
            "control": self.control_cost,
            "length": self.length,
            "information_nats": self.information,
            "planner": self.planner_cost(alpha),
        }

    # ---------------------------------------------------------------- files
    def to_dict(self) -> dict[str, Any]:
        return {
            "x": self.x.tolist(),
            "P": self.P.tolist(),
            "P_prior": self.P_prior.tolist(),
            "S": self.S.tolist(),
            "noise": self.noise,
            "meta": self.meta,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "BeliefPath":
        if not isinstance(data, dict):
            raise ValidationError("path", "must be an object")
        missing = {"x", "P", "P_prior", "S"} - set(data)
        if missing:
            raise ValidationError(f"path.{sorted(missing)[0]}", "missing")
        return cls(np.array(data["x"], float), np.array(data["P"], float), np.array(data["P_prior"], float),
                   np.array(data["S"], float), data.get("noise", "per_step"), dict(data.get("meta", {})))

    def save(self, path: str | Path) -> Path:
        """Write as ``.json`` or ``.npz`` (by suffix); :meth:`load` reads it back equal."""
        path = Path(path)
        if path.suffix == ".json":
            path.write_text(json.dumps(self.to_dict()))
        elif path.suffix == ".npz":
            np.savez(path, x=self.x, P=self.P, P_prior=self.P_prior, S=self.S,
                     noise=np.array(self.noise), meta=np.array(json.dumps(self.meta)))
        else:
            raise ValidationError("path", f"belief paths are saved as .json or .npz, got {path.suffix!r}")
        return path

    @classmethod
    def load(cls, path: str | Path) -> "BeliefPath":
        path = Path(path)
        if not path.exists():
            raise ValidationError("path", f"no such file: {path}")
        if path.suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                return cls(z["x"], z["P"], z["P_prior"], z["S"], str(z["noise"]), json.loads(str(z["meta"])))
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ValidationError("path", f"{path}: malformed JSON: {exc}") from exc
        if isinstance(data, dict) and "path" in data and "x" not in data:
            data = data["path"]  # a result file holding a path
        return cls.from_dict(data)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, BeliefPath):
            return NotImplemented
        return (self.noise == other.noise and self.meta == other.meta
                and all(np.array_equal(getattr(self, f), getattr(other, f)) for f in ("x", "P", "P_prior", "S")))

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"BeliefPath(K={self.K}, d={self.dim}, noise={self.noise!r}, length={self.length:.4g} m)"
