"""Confidence ellipses (2-D patches) and ellipsoids (3-D meshes) of Gaussian beliefs."""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.collections import PatchCollection
from matplotlib.patches import Ellipse

from .figure import _is_3d


def _semi_axes(P: np.ndarray, chi2: float) -> tuple[np.ndarray, np.ndarray]:
    """Semi-axis lengths (ascending) and unit directions (columns) of the
    ellipse {y : (y-x)^T P^-1 (y-x) <= chi2}."""
    P = np.asarray(P, dtype=float)
    lam, V = np.linalg.eigh(0.5 * (P + P.T))
    return np.sqrt(chi2 * np.clip(lam, 0.0, None)), V


def _ellipse_patch(x: np.ndarray, P: np.ndarray, chi2: float, **style: Any) -> Ellipse:
    r, V = _semi_axes(P, chi2)
    major = V[:, 1]
    angle = float(np.degrees(np.arctan2(major[1], major[0])))
    return Ellipse(xy=(float(x[0]), float(x[1])), width=2 * r[1], height=2 * r[0], angle=angle, **style)


def _ellipsoid_quads(x: np.ndarray, P: np.ndarray, chi2: float, n_lon: int = 16, n_lat: int = 8) -> np.ndarray:
    """(n_lon * n_lat, 4, 3) quadrilaterals meshing the surface of a 3-D ellipsoid."""
    r, V = _semi_axes(P, chi2)
    u = np.linspace(0.0, 2 * np.pi, n_lon + 1)
    v = np.linspace(0.0, np.pi, n_lat + 1)
    sphere = np.stack([np.outer(np.cos(u), np.sin(v)),
                       np.outer(np.sin(u), np.sin(v)),
                       np.outer(np.ones_like(u), np.cos(v))], axis=-1)
    pts = np.asarray(x, dtype=float) + (sphere * r) @ V.T  # y = x + V diag(r) s
    quads = np.stack([pts[:-1, :-1], pts[1:, :-1], pts[1:, 1:], pts[:-1, 1:]], axis=2)
    return quads.reshape(-1, 4, 3)


def plot_ellipse(ax, x, P, chi2: float, **style: Any):
    """Draw the confidence ellipse {y : (y-x)^T P^-1 (y-x) <= chi2}.

    2-D axes: a :class:`matplotlib.patches.Ellipse` whose semi-axes are
    ``sqrt(chi2 * eig(P))`` along the eigenvectors of ``P`` (outline only
    unless ``facecolor`` is given; ``color`` sets the outline). 3-D axes: the
    ellipsoid as one translucent mesh (see :func:`plot_ellipses`). A singular
    ``P`` gives a flat (or point) ellipse. Returns the artist.
    """
    x = np.asarray(x, dtype=float)
    if _is_3d(ax):
        return plot_ellipses(ax, x[None], np.asarray(P, dtype=float)[None], chi2, **style)
    style = dict(style)
    color = style.pop("color", None)
    style.setdefault("facecolor", "none")
    style.setdefault("edgecolor", color if color is not None else "black")
    style.setdefault("linewidth", 0.8)
    patch = _ellipse_patch(x, P, chi2, **style)
    ax.add_patch(patch)
    return patch


def plot_ellipses(ax, xs, Ps, chi2: float, **style: Any):
    """Draw many confidence ellipses as a single collection (fast).

    ``xs`` is (n, d) centres, ``Ps`` (n, d, d) covariances. 2-D: a
    :class:`~matplotlib.collections.PatchCollection` of ellipses (outline only
    by default; ``color`` sets the outline, other keywords go to the
    collection). 3-D: a ``Poly3DCollection`` meshing every ellipsoid
    (``color`` sets the surface; default alpha 0.15). Returns the collection.
    """
    xs = np.asarray(xs, dtype=float)
    Ps = np.asarray(Ps, dtype=float)
    if xs.ndim != 2 or Ps.shape != (xs.shape[0], xs.shape[1], xs.shape[1]):
        raise ValueError(f"need xs (n, d) and Ps (n, d, d), got {xs.shape} and {Ps.shape}")
    style = dict(style)
    color = style.pop("color", None)
    if _is_3d(ax):
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection

        quads = [_ellipsoid_quads(x, P, chi2) for x, P in zip(xs, Ps)]
        style.setdefault("facecolor", color if color is not None else "tab:blue")
        style.setdefault("edgecolor", "none")
        style.setdefault("alpha", 0.15)
        coll = Poly3DCollection(np.concatenate(quads) if quads else np.zeros((0, 4, 3)), **style)
        ax.add_collection3d(coll)
        return coll
    style.setdefault("facecolor", "none")
    style.setdefault("edgecolor", color if color is not None else "black")
    style.setdefault("linewidth", 0.8)
    coll = PatchCollection([_ellipse_patch(x, P, chi2) for x, P in zip(xs, Ps)], **style)
    ax.add_collection(coll)
    return coll
