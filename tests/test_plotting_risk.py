"""plot_risk_allocation: ellipses at each transition's own level beside the risk
allotted per transition, on a real smoothed path of paper-multi."""

import matplotlib

matplotlib.use("Agg")

import matplotlib.image as mpimg  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from scipy.special import ndtr  # noqa: E402

import belief_nlp as bn  # noqa: E402
from belief_nlp import plotting as bp  # noqa: E402
from belief_nlp.allocation import RiskAllocation  # noqa: E402

K = 8


@pytest.fixture(scope="module")
def sc():
    return bn.load_scenario("paper-multi")


@pytest.fixture(scope="module")
def planned(sc):
    return bn.plan(sc, n_nodes=150, seed=0)


@pytest.fixture(scope="module")
def smoothed(sc, planned):
    """A real smoothed path (a small plan, K = 8, at the scenario's fixed level); figures closed at the end."""
    yield bn.smooth(sc, planned.path, K=K, method="ipopt")
    plt.close("all")


def _heights(ax):
    return np.array([p.get_height() for p in bp.find_artists(ax, "risk-bars")])


def _allocation(sc, K, rng, hot=((2, 0), (5, 3))):
    """A hand-made allocation: small random risks with two hot pairs; levels = g^-1(risk)."""
    J = len(sc.hazards)
    risk = rng.uniform(1e-6, 1e-4, (K, J))
    for k, j in hot:
        risk[k, j] = 0.01
    levels = (-np.asarray([[_inv_tail(p) for p in row] for row in risk])) ** 2
    return RiskAllocation(budget=0.05, allocation=risk, levels=levels, bound=float(risk.sum()) * 0.9,
                          method="optimal", hazard_names=tuple(h.name for h in sc.hazards))


def _inv_tail(p):
    """Phi^-1(p) by bisection on scipy's ndtr (independent of the library's ndtri use)."""
    lo, hi = -40.0, 0.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ndtr(mid) < p else (lo, mid)
    return 0.5 * (lo + hi)


def test_fixed_level_result_is_drawn_from_its_certified_bounds(sc, smoothed, tmp_path):
    assert getattr(smoothed, "risk", None) is None            # smoothed at the scenario's fixed level
    fig, (ax_map, ax_bar) = bp.plot_risk_allocation(sc, smoothed)
    assert isinstance(fig, matplotlib.figure.Figure)
    assert ax_map in fig.axes and ax_bar in fig.axes
    assert len(fig.axes) == 3                                  # the two panels and the map's colour bar
    # bars: one per transition, summing to the path's certified step-time bound (independent: verify)
    report = bn.verify(sc, smoothed)
    h = _heights(ax_bar)
    assert len(h) == smoothed.path.K == K
    assert h.sum() == pytest.approx(np.sum(report.risk.pairs), rel=1e-9)
    np.testing.assert_allclose(h, report.risk.per_transition(), rtol=1e-9)
    (bound,) = bp.find_artists(ax_bar, "risk-bound")
    assert bound.get_ydata()[0] == pytest.approx(report.risk_bound, rel=1e-9)
    assert not bp.find_artists(ax_bar, "risk-budget")          # no budget was given: no line
    assert "fixed" in ax_bar.get_title() and "no budget" in ax_bar.get_title()
    # K + 1 ellipses; ellipse k at transition k's smallest clearance (the start at transition 1's)
    (ell,) = bp.find_artists(ax_map, "risk-ellipses")
    paths = ell.get_paths()
    assert len(paths) == K + 1
    tau = np.min(report.risk.clearance, axis=1)
    tau = np.concatenate([tau[:1], tau])
    P = smoothed.path.P
    for i in (1, K // 2, K):
        ext = ell.get_transforms()[i] if len(ell.get_transforms()) > 1 else None
        outline = paths[i] if ext is None else paths[i].transformed(matplotlib.transforms.Affine2D(ext))
        box = outline.get_extents()
        half = np.sqrt(tau[i] * np.diag(P[i]))                 # support function of the ellipse along e_1, e_2
        np.testing.assert_allclose([box.width / 2, box.height / 2], half, rtol=1e-3)
        np.testing.assert_allclose([box.x0 + box.width / 2, box.y0 + box.height / 2], smoothed.path.x[i],
                                   atol=1e-6)
    # the paper's fixed-level ellipses for reference, and the mean path
    assert len(bp.find_artists(ax_map, "posterior-ellipses")[0].get_paths()) == K + 1
    (line,) = bp.find_artists(ax_map, "mean-path")
    np.testing.assert_allclose(np.column_stack(line.get_data()), smoothed.path.x)
    out = bp.save_figure(fig, tmp_path / "risk.png", dpi=60)
    assert out.stat().st_size > 0
    img = mpimg.imread(out)
    assert img.shape[0] > 100 and len(np.unique(img.reshape(-1, img.shape[-1])[::50], axis=0)) > 5


def test_budgeted_result_is_drawn_from_its_allocation(sc, planned):
    res = bn.smooth(sc, planned.path, K=K, method="ipopt", risk=0.1)      # optimal allocation
    alloc = res.risk
    assert alloc.allocation.shape == (K, len(sc.hazards))
    fig, (ax_map, ax_bar) = bp.plot_risk_allocation(sc, res, log=True)
    h = _heights(ax_bar)
    np.testing.assert_allclose(h, alloc.allocation.sum(axis=1), rtol=1e-12)
    assert h.sum() == pytest.approx(alloc.allotted, rel=1e-12) and h.sum() <= 0.1 * (1 + 1e-9)
    (budget,) = bp.find_artists(ax_bar, "risk-budget")
    (bound,) = bp.find_artists(ax_bar, "risk-bound")
    assert budget.get_ydata()[0] == 0.1 and bound.get_ydata()[0] == alloc.bound
    assert "optimal" in ax_bar.get_title()
    # ellipse k at min_j levels[k-1, j]: its extent along each axis is sqrt(tau P_ii)
    (ell,) = bp.find_artists(ax_map, "risk-ellipses")
    tau = np.min(alloc.levels, axis=1)
    for k in range(1, K + 1):
        box = ell.get_paths()[k].get_extents()
        np.testing.assert_allclose([box.width / 2, box.height / 2], np.sqrt(tau[k - 1] * np.diag(res.path.P[k])),
                                   rtol=1e-3)


def test_explicit_allocation_stacked_and_dominant(sc, smoothed):
    alloc = _allocation(sc, K, np.random.default_rng(3))
    fig, (ax_map, ax_bar) = bp.plot_risk_allocation(sc, smoothed.path, alloc, bars="stacked")
    h = _heights(ax_bar)
    assert len(h) == K * len(sc.hazards)                       # one segment per pair
    assert h.sum() == pytest.approx(alloc.allocation.sum(), rel=1e-12)
    (budget,) = bp.find_artists(ax_bar, "risk-budget")
    assert budget.get_ydata()[0] == 0.05
    # ellipse colours rank the transitions by their risk: read each colour back as its place in the map
    (ell,) = bp.find_artists(ax_map, "risk-ellipses")
    colours = np.asarray(ell.get_edgecolor())
    assert len(colours) == K + 1
    lut = plt.get_cmap("plasma")(np.linspace(0.0, 1.0, 256))
    place = np.argmin(np.linalg.norm(colours[:, None, :3] - lut[None, :, :3], axis=2), axis=1)
    assert place[0] == place[1]                                # the start takes transition 1's colour
    per_k = alloc.allocation.sum(axis=1)
    assert np.all(np.diff(place[1:][np.argsort(per_k)]) >= 0)
    assert place[3] > place[1] + 100 and place[6] > place[1] + 100   # the hot transitions 3 and 6 stand out

    fig, (ax_map, ax_bar) = bp.plot_risk_allocation(sc, smoothed.path, alloc, log=True)
    h = _heights(ax_bar)
    np.testing.assert_allclose(h, alloc.allocation.sum(axis=1), rtol=1e-12)
    assert ax_bar.get_yscale() == "log"
    labels = [t.get_text() for t in ax_bar.get_legend().get_texts()]
    assert sc.hazards[0].name in labels and sc.hazards[3].name in labels     # the hot pairs' hazards
    # bars coloured by their dominant hazard: the hot transitions' hazards differ, so do their colours
    bars = bp.find_artists(ax_bar, "risk-bars")
    assert not np.allclose(bars[2].get_facecolor(), bars[5].get_facecolor())


def test_a_given_pair_of_axes_is_used(sc, smoothed):
    fig, axes = plt.subplots(1, 2)
    out, (a, b) = bp.plot_risk_allocation(sc, smoothed, ax=axes, title="study")
    assert out is fig and a is axes[0] and b is axes[1]
    assert fig._suptitle.get_text() == "study"


def test_mismatched_allocation_is_a_validation_error(sc, smoothed):
    alloc = _allocation(sc, K, np.random.default_rng(0))
    short = RiskAllocation(0.05, alloc.allocation[:-1], alloc.levels[:-1], 0.01, "optimal")
    with pytest.raises(bn.ValidationError, match=r"allocation.*\(7, 10\).*K = 8") as exc:
        bp.plot_risk_allocation(sc, smoothed, short)
    assert exc.value.field == "allocation"
    wrong_levels = RiskAllocation(0.05, alloc.allocation, alloc.levels[:, :3], 0.01, "optimal")
    with pytest.raises(bn.ValidationError, match="levels") as exc:
        bp.plot_risk_allocation(sc, smoothed, wrong_levels)
    assert exc.value.field == "allocation"
    negative = RiskAllocation(0.05, -alloc.allocation, alloc.levels, 0.01, "optimal")
    with pytest.raises(bn.ValidationError) as exc:
        bp.plot_risk_allocation(sc, smoothed, negative)
    assert exc.value.field == "allocation"
    for kwargs, field in (({"allocation": alloc.allocation}, "allocation"), ({"bars": "pie"}, "bars"),
                          ({"bars": "stacked", "log": True}, "bars"), ({"ax": plt.gca()}, "ax")):
        with pytest.raises(bn.ValidationError) as exc:
            bp.plot_risk_allocation(sc, smoothed, **kwargs)
        assert exc.value.field == field
    with pytest.raises(bn.ValidationError) as exc:
        bp.plot_risk_allocation(sc, smoothed.path.x)
    assert exc.value.field == "result_or_path"


def test_three_d_scenario(tmp_path):
    sc3 = bn.load_scenario("cube3d")
    x = np.linspace(sc3.x0, [0.82, 0.82, 0.82], 11)
    x[3:8, 1] += 0.3
    path = bn.BeliefPath.from_sensing(x, sc3.P0, np.broadcast_to(1e4 * np.eye(3), (10, 3, 3)), W=sc3.W)
    fig, (ax_map, ax_bar) = bp.plot_risk_allocation(sc3, path, log=True)
    assert ax_map.name == "3d"
    assert _heights(ax_bar).sum() == pytest.approx(bp.fixed_allocation(sc3, path).allotted, rel=1e-12)
    assert bp.save_figure(fig, tmp_path / "cube.png", dpi=50).stat().st_size > 0
    plt.close("all")
