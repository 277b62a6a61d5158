"""Scenario families for studies: maps generated deterministically from (family, seed).

``generate("random-polygons", 3)`` always returns the same validated
:class:`~belief_nlp.Scenario` (on any machine: the generator is numpy's PCG64
seeded from the family's name and the seed, and only elementary arithmetic
follows). Save one with :func:`belief_nlp.save_scenario` to get a scenario
file.

Families
--------
``random-polygons``
    The unit square with 4 to 7 random convex polygons (hulls of random points
    around random centres). Polygons are kept apart by their bounding discs,
    so they never overlap; the start (0.1, 0.5) and the target box
    [0.8, 0.9] x [0.45, 0.55] are kept clear by a margin.
``corridor``
    The unit square crossed by one or two walls, each with one narrow gap
    (0.08 to 0.16 m wide) at a random height: the robot must thread the
    passages. Start on the left, target on the right.
``boxes3d``
    The unit cube with 3 to 5 axis-aligned boxes, pairwise separated, clear of
    the start (0.1, 0.1, 0.1) and the target box [0.8, 0.9]^3.

Spec strings (studies, the CLI): ``"random-polygons:4"`` is maps 0..3,
``"random-polygons@7"`` is map 7 alone.
"""

from __future__ import annotations

import hashlib
from typing import Callable

import numpy as np

from .errors import ValidationError
from .scenario import Scenario, scenario_from_dict

__all__ = ["FAMILIES", "generate", "parse_family_spec", "is_family_spec"]

_NOISE = {"W": [[0.2e-3, 0.0], [0.0, 0.2e-3]], "W_rate": [[1e-3, 0.0], [0.0, 1e-3]]}
_CLEAR = 0.08    # free radius around the start and around the target (m): room for the first ellipses


def _rng(family: str, seed: int) -> np.random.Generator:
    # The family's name enters the seed so that two families with the same
    # seed do not share random numbers; sha256 is stable across processes
    # (Python's hash() is salted per process).
    salt = int.from_bytes(hashlib.sha256(family.encode()).digest()[:8], "little")
    return np.random.default_rng([salt, int(seed)])


def _base(name: str, description: str, dim: int) -> dict:
    if dim == 2:
        noise = _NOISE
        return {"name": name, "description": description, "confidence": 0.9, "alpha": 0.1,
                "start": {"x": [0.1, 0.5], "P": [[1e-9, 0.0], [0.0, 1e-9]]}, "noise": noise,
                "domain": {"box": {"lower": [0.0, 0.0], "upper": [1.0, 1.0]}},
                "target": {"box": {"lower": [0.8, 0.45], "upper": [0.9, 0.55]}},
                "horizon": {"K": 20},
                # the smoother's per-step model, and a rewiring cap growing with alpha, as paper-multi
                "planner": {"noise": "per_step", "max_radius": 0.3, "radius_per_alpha": 1.2}}
    return {"name": name, "description": description, "confidence": 0.9, "alpha": 0.1,
            "start": {"x": [0.1, 0.1, 0.1], "P": 1e-9}, "noise": {"W": 0.2e-3, "W_rate": 1e-3},
            "domain": {"box": {"lower": [0.0] * 3, "upper": [1.0] * 3}},
            "target": {"box": {"lower": [0.8] * 3, "upper": [0.9] * 3}},
            # goal_bias 0.2: the target is 1e-3 of the box here (1e-2 in 2-D); with
            # 0.05, 500 nodes found no path at alpha = 1 on 4 of maps 0-4 (0.2: 5 of 5)
            "horizon": {"K": 10}, "planner": {"noise": "per_step", "max_radius": 0.4, "radius_per_alpha": 1.2,
                                              "goal_bias": 0.2}}


def _box_distance(c: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> float:
    """Euclidean distance from point c to an axis-aligned box."""
    return float(np.linalg.norm(np.maximum(0.0, np.maximum(lower - c, c - upper))))


def _convex_polygon(rng: np.random.Generator, centre: np.ndarray, radius: float) -> np.ndarray:
    """Counter-clockwise vertices of a random convex polygon within ``radius`` of ``centre``.

    Points at sorted random angles on radii in [0.6, 1] x radius, then their
    convex hull (a monotone-chain hull: a few lines, no Qhull call).
    """
    n = int(rng.integers(3, 8))
    ang = np.sort(rng.uniform(0.0, 2 * np.pi, n))
    r = radius * rng.uniform(0.6, 1.0, n)
    pts = centre + np.c_[r * np.cos(ang), r * np.sin(ang)]
    pts = pts[np.lexsort((pts[:, 1], pts[:, 0]))]

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 1e-12:
            lower.pop()
        lower.append(p)
    upper: list = []
    for p in pts[::-1]:
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 1e-12:
            upper.pop()
        upper.append(p)
    hull = np.array(lower[:-1] + upper[:-1])
    if len(hull) < 3:       # all points nearly collinear: fall back to a triangle
        a = rng.uniform(0, 2 * np.pi)
        hull = centre + radius * np.c_[np.cos(a + np.array([0, 2.1, 4.2])), np.sin(a + np.array([0, 2.1, 4.2]))]
    return np.round(hull, 6)


def _random_polygons(seed: int) -> dict:
    rng = _rng("random-polygons", seed)
    data = _base(f"random-polygons-{seed}", f"Random convex polygons, map {seed} (belief_nlp.families).", 2)
    start = np.array(data["start"]["x"])
    t_lo, t_hi = np.array([0.8, 0.45]), np.array([0.9, 0.55])
    want = int(rng.integers(4, 8))
    discs: list[tuple[np.ndarray, float]] = []
    obstacles = []
    for _ in range(400):                      # rejection sampling, bounded
        if len(discs) == want:
            break
        r = float(rng.uniform(0.05, 0.12))
        c = rng.uniform(r + 0.02, 1.0 - r - 0.02, 2)
        if np.linalg.norm(c - start) < r + _CLEAR or _box_distance(c, t_lo, t_hi) < r + _CLEAR:
            continue
        # discs 0.03 m apart: polygons inside them cannot touch
        if any(np.linalg.norm(c - c2) < r + r2 + 0.03 for c2, r2 in discs):
            continue
        discs.append((c, r))
        obstacles.append({"name": f"obstacle {len(discs)}", "vertices": _convex_polygon(rng, c, r).tolist()})
    data["obstacles"] = obstacles
    return data


def _corridor(seed: int) -> dict:
    rng = _rng("corridor", seed)
    data = _base(f"corridor-{seed}", f"Walls with narrow gaps, map {seed} (belief_nlp.families).", 2)
    n_walls = int(rng.integers(1, 3))
    xs = [0.45] if n_walls == 1 else [0.35, 0.6]
    obstacles = []
    for i, x in enumerate(xs):
        width = float(rng.uniform(0.08, 0.16))
        thick = float(rng.uniform(0.04, 0.08))
        centre = float(rng.uniform(0.2 + width / 2, 0.8 - width / 2))
        lo, hi = round(centre - width / 2, 6), round(centre + width / 2, 6)
        x0, x1 = round(x - thick / 2, 6), round(x + thick / 2, 6)
        obstacles.append({"name": f"wall {i + 1} low", "box": {"lower": [x0, 0.0], "upper": [x1, lo]}})
        obstacles.append({"name": f"wall {i + 1} high", "box": {"lower": [x0, hi], "upper": [x1, 1.0]}})
    data["obstacles"] = obstacles
    return data


def _boxes3d(seed: int) -> dict:
    rng = _rng("boxes3d", seed)
    data = _base(f"boxes3d-{seed}", f"Random boxes in the unit cube, map {seed} (belief_nlp.families).", 3)
    start = np.array(data["start"]["x"])
    t_lo, t_hi = np.full(3, 0.8), np.full(3, 0.9)
    want = int(rng.integers(3, 6))
    boxes: list[tuple[np.ndarray, np.ndarray]] = []
    for _ in range(400):
        if len(boxes) == want:
            break
        half = rng.uniform(0.05, 0.15, 3)
        c = rng.uniform(half + 0.02, 1.0 - half - 0.02)
        lo, hi = np.round(c - half, 6), np.round(c + half, 6)
        if _box_distance(start, lo, hi) < _CLEAR or _box_distance(c, t_lo, t_hi) < float(np.max(half)) + _CLEAR:
            continue
        # separated along some axis by 0.03 m: boxes cannot touch
        if any(not np.any((lo > hi2 + 0.03) | (lo2 > hi + 0.03)) for lo2, hi2 in boxes):
            continue
        boxes.append((lo, hi))
    data["obstacles"] = [{"name": f"box {i + 1}", "box": {"lower": lo.tolist(), "upper": hi.tolist()}}
                         for i, (lo, hi) in enumerate(boxes)]
    return data


#: family name -> generator of the scenario's file tree from a seed
FAMILIES: dict[str, Callable[[int], dict]] = {
    "random-polygons": _random_polygons,
    "corridor": _corridor,
    "boxes3d": _boxes3d,
}


def generate(family: str, seed: int) -> Scenario:
    """The scenario number ``seed`` of ``family`` (validated; the same every time)."""
    if family not in FAMILIES:
        raise ValidationError("family", f"unknown scenario family {family!r}; known: {', '.join(FAMILIES)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValidationError("seed", f"a family seed is an integer >= 0, got {seed!r:.40}")
    return scenario_from_dict(FAMILIES[family](int(seed)), source=f"{family}@{seed}")


def is_family_spec(spec: str) -> bool:
    """Whether ``spec`` names a family ("family:count" or "family@seed")."""
    for sep in (":", "@"):
        if sep in spec and spec.split(sep, 1)[0] in FAMILIES:
            return True
    return False


def parse_family_spec(spec: str) -> list[tuple[str, int]]:
    """``"random-polygons:3"`` -> [(family, 0), (family, 1), (family, 2)];
    ``"random-polygons@7"`` -> [(family, 7)]."""
    if "@" in spec:
        family, _, rest = spec.partition("@")
        seeds = [rest]
    else:
        family, _, rest = spec.partition(":")
        seeds = None
    if family not in FAMILIES:
        raise ValidationError("scenarios", f"unknown scenario family {family!r} in {spec!r}; known: {', '.join(FAMILIES)}")
    try:
        n = int(rest)
    except ValueError:
        raise ValidationError("scenarios", f"{spec!r}: expected family:count or family@seed with an integer") from None
    if n < 0 or (seeds is None and n < 1):
        raise ValidationError("scenarios", f"{spec!r}: the count must be >= 1 and a seed >= 0")
    return [(family, n)] if seeds is not None else [(family, i) for i in range(n)]
