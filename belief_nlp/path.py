"""Belief paths: means, prior and posterior covariances, sensing, costs.

A :class:`BeliefPath` is validated once, when it is built: its arrays are
private read-only copies and cannot be reassigned, so a path that passed
validation (and :func:`~belief_nlp.verify`) cannot later be turned into
something else in place.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import belief
from ._limits import check_document, check_npz, load_json, parse_document
from .errors import ScenarioFileError, ValidationError

__all__ = ["BeliefPath", "NOISE_MODELS"]

NOISE_MODELS = ("per_step", "per_metre")
_ARRAYS = ("x", "P", "P_prior", "S")


def _float_array(value: Any, field_name: str, finite: bool = False) -> np.ndarray:
    """``value`` as a new float array; with ``finite``, NaN and inf are refused too."""
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError, RecursionError) as exc:
        raise ValidationError(field_name, f"must be a rectangular array of numbers: {str(exc)[:200]}") from exc
    if raw.dtype.kind not in "iuf":
        raise ValidationError(field_name, f"must be an array of numbers, got dtype {raw.dtype}")
    arr = raw.astype(float)
    if finite and not np.all(np.isfinite(arr)):
        raise ValidationError(field_name, "contains NaN or infinite values")
    return arr


def _values_equal(a: Any, b: Any) -> bool:
    """Equality in which NaN equals NaN, through dicts, lists and arrays.

    Results keep NaN for "not measured" (a failed run's travel, say), and a
    saved result must compare equal to itself after loading.
    """
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_values_equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_values_equal(x, y) for x, y in zip(a, b))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a_arr, b_arr = np.asarray(a), np.asarray(b)
        if a_arr.shape != b_arr.shape:
            return False
        if a_arr.dtype.kind in "fc" or b_arr.dtype.kind in "fc":
            return bool(np.array_equal(a_arr, b_arr, equal_nan=True))
        return bool(np.array_equal(a_arr, b_arr))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    try:
        return bool(a == b)
    except (TypeError, ValueError):
        return False


def _means(x: Any) -> np.ndarray:
    x = _float_array(x, "x", finite=True)
    if x.ndim != 2 or x.shape[0] < 2:
        raise ValidationError("x", f"must have shape (K+1, d) with K >= 1, got {x.shape}")
    return x


def _alpha(alpha: Any) -> float:
    """A finite, non-negative information weight (a NaN weight would make every cost NaN)."""
    try:
        a = float(alpha) if isinstance(alpha, (int, float, np.integer, np.floating)) and \
            not isinstance(alpha, (bool, np.bool_)) else math.nan
    except OverflowError:
        a = math.nan
    if not (math.isfinite(a) and a >= 0):
        raise ValidationError("alpha", f"must be a finite number >= 0, got {alpha!r:.40}")
    return a


def _meta(meta: Any) -> dict:
    if meta is None:
        return {}
    if not isinstance(meta, dict):
        raise ValidationError("meta", f"must be a dict, got {type(meta).__name__}")
    return dict(meta)


def _positive_definite(P: np.ndarray) -> bool:
    try:
        np.linalg.cholesky(0.5 * (P + P.T))
    except np.linalg.LinAlgError:
        return False
    return True


@dataclass(eq=False)
class BeliefPath:
    """A discrete belief path (x_k, P_k), k = 0..K.

    The noise added on transition k is ``P_prior[k] - P[k-1]``; during the
    transition the covariance grows linearly, P(s) = P[k-1] + s W_k
    (paper Definition 3). The arrays are validated on construction and
    read-only afterwards (build a new path with ``dataclasses.replace``);
    :meth:`from_sensing` and :meth:`from_covariances` build consistent paths.

    Parameters
    ----------
    x : array_like, shape (K+1, d)
        Means; ``x[0]`` is the start.
    P : array_like, shape (K+1, d, d)
        Posterior covariances; ``P[0]`` is the start covariance P0.
    P_prior : array_like, shape (K+1, d, d)
        Prior covariances P_hat_k = P_{k-1} + W_k (``P_prior[0] = P0``).
    S : array_like, shape (K+1, d, d)
        Sensing information, P_k = (P_prior_k^-1 + S_k)^-1 (``S[0] = 0``).
    noise : {"per_step", "per_metre"}, optional
        ``"per_step"`` (W_k = W, the smoother's model, the default) or
        ``"per_metre"`` (W_k = W_rate ||x_k - x_{k-1}||, the authors' planner).
    meta : dict, optional
        Free-form provenance (planner seed, solver, ...), JSON-serialisable.

    Raises
    ------
    ValidationError
        For arrays of the wrong shape, non-finite entries, an unknown noise
        model or a ``meta`` that is not a dict; the error names the field
        (``"path.x"``, ...).
    """

    x: np.ndarray
    P: np.ndarray
    P_prior: np.ndarray
    S: np.ndarray
    noise: str = "per_step"
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.x = _float_array(self.x, "path.x")
        self.P = _float_array(self.P, "path.P")
        self.P_prior = _float_array(self.P_prior, "path.P_prior")
        self.S = _float_array(self.S, "path.S")
        if self.meta is None:
            self.meta = {}
        if not isinstance(self.meta, dict):
            raise ValidationError("path.meta", f"must be a dict, got {type(self.meta).__name__}")
        if self.x.ndim != 2:
            raise ValidationError("path.x", f"must have shape (K+1, d), got {self.x.shape}")
        n, d = self.x.shape
        if n < 2:
            raise ValidationError("path.x", "a path needs at least two points")
        for name in ("P", "P_prior", "S"):
            arr = getattr(self, name)
            if arr.shape != (n, d, d):
                raise ValidationError(f"path.{name}", f"must have shape {(n, d, d)}, got {arr.shape}")
        for name in _ARRAYS:
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValidationError(f"path.{name}", "contains NaN or infinite values")
        if not isinstance(self.noise, str) or self.noise not in NOISE_MODELS:
            raise ValidationError("path.noise", f"must be one of {NOISE_MODELS}, got {self.noise!r:.60}")
        self.noise = str(self.noise)
        for name in _ARRAYS:
            getattr(self, name).flags.writeable = False
        object.__setattr__(self, "_validated", True)

    def __setattr__(self, name: str, value: Any) -> None:
        # The arrays and the noise model are fixed once validated (meta stays
        # free-form): build a new path instead, e.g. dataclasses.replace(p, x=...).
        if name in _ARRAYS + ("noise",) and getattr(self, "_validated", False):
            raise dataclasses.FrozenInstanceError(f"BeliefPath.{name} is read-only; build a new path "
                                                  f"(dataclasses.replace(path, {name}=...))")
        object.__setattr__(self, name, value)

    # -------------------------------------------------------------- builders
    @classmethod
    def from_sensing(cls, x, P0, S, W=None, W_rate=None, noise: str = "per_step",
                     meta: dict | None = None) -> "BeliefPath":
        """Roll the Kalman recursion forward from P0 with sensing S[1..K].

        ``S`` is (K+1, d, d) (S[0] ignored) or (K, d, d) for steps 1..K.
        Give ``W`` (per step) or ``W_rate`` (per metre) to match ``noise``.
        """
        x = _means(x)
        n, d = x.shape
        S = _float_array(S, "S", finite=True)
        if S.shape == (n - 1, d, d):
            S = np.concatenate([np.zeros((1, d, d)), S], axis=0)
        elif S.shape != (n, d, d):
            raise ValidationError("S", f"must have shape {(n - 1, d, d)} (steps 1..K) or {(n, d, d)} "
                                       f"(S[0] ignored) for x of shape {x.shape}, got {S.shape}")
        P0 = _float_array(P0, "P0", finite=True)
        if P0.shape != (d, d):
            raise ValidationError("P0", f"must have shape {(d, d)}, got {P0.shape}")
        Wk = cls._transition_noise(x, W, W_rate, noise)
        P = np.empty((n, d, d))
        Pp = np.empty((n, d, d))
        P[0] = Pp[0] = P0
        S = S.copy()
        S[0] = 0.0
        for k in range(1, n):
            Pp[k] = P[k - 1] + Wk[k - 1]
            try:
                P[k] = belief.update(Pp[k], S[k])
            except np.linalg.LinAlgError as exc:
                raise ValidationError("S", f"the Kalman update at step {k} fails ({exc}): the prior or "
                                           f"P_prior^-1 + S_{k} is not positive definite") from exc
        return cls(x, P, Pp, S, noise, _meta(meta))

    @classmethod
    def from_covariances(cls, x, P, W=None, W_rate=None, noise: str = "per_step",
                         meta: dict | None = None) -> "BeliefPath":
        """From means and posterior covariances; priors and the lossless sensing
        S_k = P_k^-1 - P_prior_k^-1 are derived (S_k may come out indefinite
        if the path is not lossless; :func:`~belief_nlp.verify` reports it)."""
        x = _means(x)
        P = _float_array(P, "P", finite=True)
        n, d = x.shape
        if P.shape != (n, d, d):
            raise ValidationError("P", f"must have shape {(n, d, d)} for x of shape {x.shape}, got {P.shape}")
        Wk = cls._transition_noise(x, W, W_rate, noise)
        Pp = np.empty_like(P)
        Pp[0] = P[0]
        Pp[1:] = P[:-1] + Wk
        S = np.zeros_like(P)
        with np.errstate(all="ignore"):
            try:
                S[1:] = belief.lossless_sensing(Pp[1:], P[1:])
                ok = bool(np.all(np.isfinite(S)))
            except np.linalg.LinAlgError:
                ok = False
        if not ok:
            # name the first step whose covariance cannot be inverted
            bad = next((k for k in range(1, n) if not _positive_definite(P[k])), None)
            where = f"P_{bad} is singular or not positive definite" if bad is not None else \
                "a prior covariance is not positive definite"
            raise ValidationError("P", f"the sensing S_k = P_k^-1 - P_prior_k^-1 cannot be derived: {where}")
        return cls(x, P, Pp, S, noise, _meta(meta))

    @staticmethod
    def _transition_noise(x: np.ndarray, W, W_rate, noise: str) -> np.ndarray:
        """Noise added on each transition, (K, d, d)."""
        n, d = x.shape
        if noise == "per_step":
            if W is None:
                raise ValidationError("W", "per_step noise needs W")
            W = _float_array(W, "W", finite=True)
            if W.shape not in ((d, d), (n - 1, d, d)):
                raise ValidationError("W", f"must have shape {(d, d)} or {(n - 1, d, d)}, got {W.shape}")
            return np.broadcast_to(W, (n - 1, d, d)).copy()
        if noise == "per_metre":
            if W_rate is None:
                raise ValidationError("W_rate", "per_metre noise needs W_rate")
            W_rate = _float_array(W_rate, "W_rate", finite=True)
            if W_rate.shape != (d, d):
                raise ValidationError("W_rate", f"must have shape {(d, d)}, got {W_rate.shape}")
            lengths = np.linalg.norm(np.diff(x, axis=0), axis=1)
            return lengths[:, None, None] * W_rate[None]
        raise ValidationError("noise", f"must be one of {NOISE_MODELS}, got {noise!r:.60}")

    # ------------------------------------------------------------ properties
    @property
    def K(self) -> int:
        """Number of transitions."""
        return self.x.shape[0] - 1

    @property
    def dim(self) -> int:
        """Dimension d of the space (2 or 3)."""
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
        return self.control_cost + _alpha(alpha) * self.information

    def planner_cost(self, alpha: float) -> float:
        """The planner's cost: length + alpha * information (nats)."""
        return self.length + _alpha(alpha) * self.information

    @property
    def step_information(self) -> np.ndarray:
        """(K,) information 1/2 (log det P_prior_k - log det P_k) of each step, nats."""
        return np.asarray(belief.information_cost(self.P_prior[1:], self.P[1:]), dtype=float).reshape(self.K)

    @property
    def step_control(self) -> np.ndarray:
        """(K,) control cost ||x_k - x_{k-1}||^2 of each step, m^2."""
        return np.sum(np.diff(self.x, axis=0) ** 2, axis=1)

    @property
    def sensing_steps(self) -> np.ndarray:
        """1-based indices k of the steps with a measurement (S_k != 0)."""
        return np.nonzero(np.any(self.S[1:] != 0, axis=(1, 2)))[0] + 1

    def cost_breakdown(self, alpha: float) -> dict[str, float]:
        """Costs of the path for information weight ``alpha``.

        ``steering`` = ``control`` + alpha * ``information_nats`` (the
        smoothing paper's objective); ``planner`` = ``length`` + alpha *
        ``information_nats`` (the planner's); ``information_bits`` is the
        same information in bits, as the authors' IG-RRT* reports it.
        """
        alpha = _alpha(alpha)
        info = self.information
        return {
            "alpha": float(alpha),
            "steering": self.control_cost + alpha * info,
            "control": self.control_cost,
            "length": self.length,
            "information_nats": info,
            "information_bits": info / belief.NATS_PER_BIT,
            "planner": self.length + alpha * info,
        }

    # ---------------------------------------------------------------- files
    def to_dict(self) -> dict[str, Any]:
        """The path as JSON-ready data; :meth:`from_dict` reads it back equal.

        Returns
        -------
        dict
            ``x``, ``P``, ``P_prior`` and ``S`` as nested lists, ``noise`` and ``meta``.
        """
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
        """A path from :meth:`to_dict` output (validated like the constructor)."""
        if not isinstance(data, dict):
            raise ValidationError("path", f"must be an object, got {type(data).__name__}")
        check_document(data, "path", "path")
        missing = {"x", "P", "P_prior", "S"} - set(data)
        if missing:
            raise ValidationError(f"path.{sorted(missing)[0]}", "missing")
        unknown = set(map(str, data)) - {"x", "P", "P_prior", "S", "noise", "meta"}
        if unknown:
            raise ValidationError(f"path.{sorted(unknown)[0][:60]}", "unknown key")
        noise = data.get("noise", "per_step")
        meta = data.get("meta", {})
        if not isinstance(meta, dict):
            raise ValidationError("path.meta", f"must be an object, got {type(meta).__name__}")
        return cls(data["x"], data["P"], data["P_prior"], data["S"], noise, dict(meta))

    def save(self, path: str | os.PathLike) -> Path:
        """Write as ``.json`` or ``.npz`` (by suffix); :meth:`load` reads it back equal.

        A file that cannot be written raises
        :class:`~belief_nlp.errors.ScenarioFileError` (field ``path``); a
        ``meta`` that JSON cannot hold raises ValidationError (``path.meta``).
        """
        if not isinstance(path, (str, os.PathLike)):
            raise ValidationError("path", f"must be a file name, got {type(path).__name__}")
        path = Path(path)
        if path.suffix not in (".json", ".npz"):
            raise ValidationError("path", f"belief paths are saved as .json or .npz, got {path.suffix!r}")
        try:
            meta_text = json.dumps(self.meta, allow_nan=False)
        except (TypeError, ValueError, RecursionError) as exc:
            raise ValidationError("path.meta", f"cannot be written as JSON: {exc}") from exc
        try:
            if path.suffix == ".json":
                path.write_text(json.dumps(self.to_dict(), allow_nan=False))
            else:
                np.savez(path, x=self.x, P=self.P, P_prior=self.P_prior, S=self.S,
                         noise=np.array(self.noise), meta=np.array(meta_text))
        except OSError as exc:
            raise ScenarioFileError("path", f"cannot write {str(path)[:200]}: {exc}") from exc
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> "BeliefPath":
        """Read a path written by :meth:`save` (``.npz``; anything else is read as JSON).

        Files are limited to 128 MiB (NPZ members to 512 MiB unpacked) and 32
        levels of nesting. A file that is missing, unreadable, malformed, not
        a zip archive (``.npz``) or beyond the limits raises
        :class:`~belief_nlp.errors.ScenarioFileError` (field ``path``); bad
        contents raise :class:`~belief_nlp.errors.ValidationError` naming the
        field (``path.P``, ...).
        """
        if not isinstance(path, (str, os.PathLike)):
            raise ValidationError("path", f"must be a file name, got {type(path).__name__}")
        path = Path(path)
        if path.suffix == ".npz":
            check_npz(path, "path")
            try:
                with np.load(path, allow_pickle=False) as z:
                    missing = {"x", "P", "P_prior", "S", "noise", "meta"} - set(z.files)
                    if missing:
                        raise ValidationError(f"path.{sorted(missing)[0]}", f"missing in {str(path)[:200]}")
                    arrays = [z[k] for k in _ARRAYS]
                    noise, meta_text = z["noise"], z["meta"]
            except ValidationError:
                raise
            except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
                raise ScenarioFileError("path", f"{str(path)[:200]}: not a belief-path NPZ file: "
                                                f"{str(exc)[:200]}") from exc
            if noise.ndim != 0 or meta_text.ndim != 0 or noise.dtype.kind != "U" or meta_text.dtype.kind != "U":
                raise ValidationError("path.noise" if noise.ndim != 0 or noise.dtype.kind != "U" else "path.meta",
                                      "must be a single string")
            meta = parse_document(str(meta_text), "json", f"{str(path)[:200]} (meta)", "path.meta")
            if not isinstance(meta, dict):
                raise ValidationError("path.meta", f"must be an object, got {type(meta).__name__}")
            return cls(*arrays, str(noise), meta)
        data = load_json(path, "path")
        if isinstance(data, dict) and "path" in data and "x" not in data:
            data = data["path"]  # a result file holding a path
        return cls.from_dict(data)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, BeliefPath):
            return NotImplemented
        return (self.noise == other.noise and _values_equal(self.meta, other.meta)
                and all(np.array_equal(getattr(self, f), getattr(other, f)) for f in _ARRAYS))

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"BeliefPath(K={self.K}, d={self.dim}, noise={self.noise!r}, length={self.length:.4g} m)"


def result_path(obj: Any) -> BeliefPath | None:
    """The ``.path`` of a result (PlanResult, SmoothResult, ...); None when
    ``obj`` has no ``.path``. A result whose ``.path`` is None (a failed
    plan) raises ValidationError of ``path`` with the result's message."""
    if isinstance(obj, (str, bytes, os.PathLike)):
        return None
    inner = getattr(obj, "path", None)
    if isinstance(inner, BeliefPath):
        return inner
    if inner is None and hasattr(obj, "path"):
        why = getattr(obj, "message", "")
        raise ValidationError("path", f"the {type(obj).__name__} holds no path" + (f" ({why})" if why else ""))
    return None
