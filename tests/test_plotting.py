import matplotlib

matplotlib.use("Agg")

from types import SimpleNamespace  # noqa: E402

import matplotlib.image as mpimg  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from PIL import Image, ImageSequence  # noqa: E402

import belief_nlp as bn  # noqa: E402
from belief_nlp import plotting as bp  # noqa: E402


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


@pytest.fixture(scope="module")
def sc():
    return bn.load_scenario("paper-multi")


def _path(sc, bend=0.0):
    """A safe hand-made path around the left of paper-multi, S_k = 1e4 I."""
    way = np.array([[0.15, 0.5], [0.05, 0.35], [0.06, 0.06], [0.4, 0.045 + bend], [0.65, 0.05]])
    x = np.vstack([np.linspace(way[i], way[i + 1], 5, endpoint=False) for i in range(len(way) - 1)]
                  + [way[-1:]])
    S = np.broadcast_to(1e4 * np.eye(2), (len(x) - 1, 2, 2))
    return bn.BeliefPath.from_sensing(x, sc.P0, S, W=sc.W)


def _assert_real_image(png, min_side=100):
    img = mpimg.imread(png)
    assert img.shape[0] >= min_side and img.shape[1] >= min_side
    flat = img.reshape(-1, img.shape[-1])
    assert len(np.unique(flat[:: max(1, len(flat) // 20000)], axis=0)) > 5  # not a single colour


def test_hand_made_path_is_safe(sc):
    assert bn.verify(sc, _path(sc)).safe


def test_scenario_and_belief_path_figures(sc, tmp_path):
    fig, ax = bp.plot_scenario(sc, annotate=True)
    assert isinstance(fig, matplotlib.figure.Figure) and isinstance(ax, matplotlib.axes.Axes)
    assert len(bp.find_artists(ax, "obstacle")) == len(sc.obstacles)
    assert len(bp.find_artists(ax, "target")) == 1 and len(bp.find_artists(ax, "start")) == 1
    assert ax.get_aspect() == 1.0
    _assert_real_image(bp.save_figure(fig, tmp_path / "a" / "b" / "scenario.png"))

    path = _path(sc)
    fig, ax = bp.plot_belief_path(sc, path, title=True, legend=True)
    assert f"{path.steering_cost(sc.alpha):.4g}" in ax.get_title()
    (prior,) = bp.find_artists(ax, "prior-ellipses")
    (post,) = bp.find_artists(ax, "posterior-ellipses")
    assert len(prior.get_paths()) == path.K and len(post.get_paths()) == path.K + 1
    (line,) = bp.find_artists(ax, "mean-path")
    np.testing.assert_allclose(np.column_stack(line.get_data()), path.x)
    out = bp.save_figure(fig, tmp_path / "path.png", dpi=80)
    assert out.exists()
    _assert_real_image(out)


def test_title_cost_uses_the_given_alpha(sc, tmp_path):
    path = _path(sc)
    alpha = 10 * sc.alpha + 1.0  # a path smoothed at another alpha than the scenario's
    at_sc, at_alpha = (f"{path.steering_cost(a):.4g}" for a in (sc.alpha, alpha))
    assert at_sc != at_alpha
    fig, ax = bp.plot_belief_path(sc, path, title=True, alpha=alpha)
    assert f"cost = {at_alpha}" in ax.get_title() and f"alpha = {alpha:g}" in ax.get_title()
    fig, ax = bp.plot_belief_path(sc, path, title=True)  # default: the scenario's alpha, title as before
    assert ax.get_title().endswith(f"cost = {at_sc}")
    fig, ax = bp.plot_belief_path(sc, path, title=True, cost=1.25, alpha=alpha)  # cost= wins
    assert "cost = 1.25" in ax.get_title()
    fig, ax = plt.subplots()  # the GIF's frame titles follow the same alpha
    bp.animate_smoothing(sc, [path], tmp_path / "a.gif", dpi=30, ax=ax, alpha=alpha)
    assert ax.get_title() == f"CCP iteration 0: cost {path.steering_cost(alpha):.5g}"


def _independent_semi_axes(P, chi2):
    """Semi-axes via the closed-form eigenvalues of a symmetric 2x2 matrix."""
    a, b, d = P[0, 0], P[0, 1], P[1, 1]
    mean, disc = 0.5 * (a + d), np.hypot(0.5 * (a - d), b)
    return np.sqrt(chi2 * (mean + disc)), np.sqrt(chi2 * (mean - disc))


@pytest.mark.parametrize("P", [np.array([[4e-4, 1.5e-4], [1.5e-4, 1e-4]]),
                               np.array([[1e-4, -2e-4], [-2e-4, 9e-4]]),
                               np.diag([3e-4, 3e-4])])
def test_ellipse_geometry(P):
    chi2 = 4.605
    x = np.array([0.3, 0.7])
    big, small = _independent_semi_axes(P, chi2)
    fig, ax = plt.subplots()
    patch = bp.plot_ellipse(ax, x, P, chi2, color="red")
    assert patch.get_edgecolor()[:3] == (1.0, 0.0, 0.0)
    assert patch.width / 2 == pytest.approx(big, rel=1e-9)
    assert patch.height / 2 == pytest.approx(small, rel=1e-9)
    # Extents of the drawn outline: the support function of the ellipse in
    # direction e_i is sqrt(chi2 * P_ii).
    outline = patch.get_patch_transform().transform_path(patch.get_path())
    ext = outline.get_extents()
    half = np.sqrt(chi2 * np.diag(P))
    np.testing.assert_allclose([ext.x0, ext.y0], x - half, rtol=0, atol=1e-4 * half.max())
    np.testing.assert_allclose([ext.x1, ext.y1], x + half, rtol=0, atol=1e-4 * half.max())
    # Points on the drawn outline (its Bezier curves evaluated) lie on
    # (y-x)^T P^-1 (y-x) = chi2.
    t = np.linspace(0.0, 1.0, 7)
    pts = np.vstack([bez(t) for bez, _ in outline.iter_bezier()])
    q = np.einsum("ni,ij,nj->n", pts - x, np.linalg.inv(P), pts - x)
    np.testing.assert_allclose(q, chi2, rtol=1e-3)

    # the batched helper draws the same ellipse
    coll = bp.plot_ellipses(ax, np.array([x, x + 0.1]), np.array([P, P]), chi2)
    ext2 = coll.get_paths()[0].get_extents()
    np.testing.assert_allclose([ext2.x0, ext2.x1], [ext.x0, ext.x1], atol=1e-12)


def test_tree_draws_one_segment_per_edge(sc):
    rng = np.random.default_rng(1)
    n = 2000
    x = rng.uniform(0.0, 1.0, (n, 2))
    x[0] = sc.x0
    parent = np.array([-1] + [int(rng.integers(0, i)) for i in range(1, n)])
    P = np.broadcast_to(1e-5 * np.eye(2), (n, 2, 2))
    tree = SimpleNamespace(x=x, parent=parent, P=P)
    fig, ax = bp.plot_tree(sc, tree, path=_path(sc), nodes=True, ellipses=True)
    (edges,) = bp.find_artists(ax, "tree-edges")
    segs = edges.get_segments()
    assert len(segs) == n - 1
    np.testing.assert_allclose(segs[4], [x[parent[5]], x[5]])
    assert len(bp.find_artists(ax, "tree-ellipses")[0].get_paths()) == n
    assert len(bp.find_artists(ax, "best-path")) == 1
    with pytest.raises(ValueError):
        bp.plot_tree(sc, SimpleNamespace(x=x, parent=parent[:-1]))


def test_animation_has_one_frame_per_path(sc, tmp_path):
    paths = [_path(sc, bend) for bend in (0.0, 0.0, 0.005, 0.01)]  # two identical on purpose
    out, anim = bp.animate_smoothing(sc, paths, tmp_path / "gif" / "smooth.gif", fps=5, dpi=40)
    assert out == tmp_path / "gif" / "smooth.gif" and out.exists()
    assert isinstance(anim, matplotlib.animation.FuncAnimation)
    with Image.open(out) as im:
        assert sum(1 for _ in ImageSequence.Iterator(im)) == len(paths)


def test_cost_history_input_forms(tmp_path):
    costs = [3.0, 2.0, 1.5, 1.4]
    record = type("Record", (), {})
    records = []
    for c in costs:
        r = record()
        r.cost = c
        records.append(r)
    forms = {
        "numbers": costs,
        "array": np.array(costs),
        "dicts": [{"cost": c, "iteration": i} for i, c in enumerate(costs)],
        "attr records": records,
        "object": SimpleNamespace(history=records),
        "object of dicts": SimpleNamespace(history=[{"cost": c} for c in costs]),
        "result dict": {"history": [{"cost": c} for c in costs]},
    }
    for name, form in forms.items():
        fig, ax = bp.plot_cost_history(form)
        (line,) = ax.get_lines()
        np.testing.assert_allclose(line.get_ydata(), costs, err_msg=name)
        np.testing.assert_array_equal(line.get_xdata(), np.arange(len(costs)))
    fig, ax = bp.plot_cost_history(forms, log=True)
    # all seven curves are equal: each later one names the first
    assert [ln.get_label() for ln in ax.get_lines()] == ["numbers"] + [f"{k} (same as numbers)"
                                                                       for k in list(forms)[1:]]
    assert ax.get_yscale() == "log"
    fig, ax = bp.plot_cost_history([costs, records], labels=["CCP", "IPOPT"])
    assert [ln.get_label() for ln in ax.get_lines()] == ["CCP", "IPOPT (same as CCP)"]
    _assert_real_image(bp.save_figure(fig, tmp_path / "cost.png", dpi=60))
    with pytest.raises(ValueError):
        bp.plot_cost_history([{"value": 1.0}])
    with pytest.raises(ValueError):
        bp.plot_cost_history([costs, costs], labels=["one"])


def test_coinciding_cost_curves_stay_visible_and_named():
    """auto's first stage is IPOPT: equal histories must not hide one another."""
    ipopt = [10.0, 9.9, 6.0, 3.1, 2.4, 2.31283]
    ccp = [10.0, 4.0, 2.5, 2.31283]
    fig, ax = bp.plot_cost_history({"auto": ipopt, "ccp": ccp, "ipopt": list(ipopt)}, log=True, marker="")
    auto, _, ip = lines = ax.get_lines()
    assert len({ln.get_linestyle() for ln in lines}) == 3        # a style each, not only a colour
    assert ip.get_zorder() > auto.get_zorder()                   # the twin is drawn over, dashed,
    assert auto.get_linewidth() > 2 * ip.get_linewidth()         # on a wide pale halo of the first
    assert ip.get_linestyle() != "-" and ip.get_visible() and auto.get_visible()
    np.testing.assert_array_equal(ip.get_ydata(), auto.get_ydata())
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["auto", "ccp", "ipopt (same as auto)"]


@pytest.mark.parametrize("low, high, expect", [
    (2.31, 10.0, None),          # notebook 03's curve: less than a decade (matplotlib labels 10 only)
    (2.31, 2.4, None),           # a narrow view: no 1-2-5 value inside, evenly spaced labels instead
    (0.39, 1.65, None),
    (1e-3, 1e3, [1e-3, 1e-2, 1e-1, 1, 10, 100, 1000]),   # decades: 1 per decade
])
def test_log_cost_axis_has_readable_labels(low, high, expect):
    fig, ax = bp.plot_cost_history({"a": np.geomspace(high, low, 30)}, log=True)
    fig.canvas.draw()
    lo, hi = ax.get_ylim()
    shown = {t.get_loc(): t.label1.get_text() for t in ax.yaxis.get_major_ticks() if lo <= t.get_loc() <= hi}
    ticks = sorted(shown)
    assert 4 <= len(ticks) <= 10
    for value, text in shown.items():          # every tick in view labelled, as a plain number
        assert float(text) == pytest.approx(value, rel=1e-3), text
    if expect is not None:
        np.testing.assert_allclose(sorted(ticks), expect)


def test_anytime_skips_infinite_costs(tmp_path):
    inf = np.inf
    run = [inf, inf, 5.0, 4.0, 4.0, 3.0]
    fig, ax = bp.plot_anytime(run)
    (line,) = ax.get_lines()
    y = np.asarray(line.get_ydata(), dtype=float)
    assert np.isnan(y[:2]).all() and not np.isinf(y).any()
    np.testing.assert_allclose(y[2:], run[2:])

    runs = [run, [inf, 6.0, 5.0, 2.0], [inf, inf, inf, inf, 7.0, 6.5, 6.0, 5.0]]
    fig, ax = bp.plot_anytime({"IG-RRT*": runs, "other": SimpleNamespace(cost_history=run)},
                              x=np.arange(10) * 50, log=True)
    median = ax.get_lines()[0]
    assert "median of 3" in median.get_label()
    # median over runs padded with their last value, inf until two runs have a solution
    np.testing.assert_allclose(np.asarray(median.get_ydata(), float),
                               [np.nan, np.nan, 5.0, 4.0, 4.0, 3.0, 3.0, 3.0], equal_nan=True)
    np.testing.assert_array_equal(median.get_xdata(), np.arange(8) * 50)
    _assert_real_image(bp.save_figure(fig, tmp_path / "anytime.png", dpi=60))


def test_cube3d_plots(tmp_path):
    sc3 = bn.load_scenario("cube3d")
    fig, ax = bp.plot_scenario(sc3)
    assert ax.name == "3d"
    # the box domain is drawn as six faces, not twelve triangles
    (domain,) = bp.find_artists(ax, "domain")
    fig.canvas.draw()  # 3-D collections project their faces at draw time
    assert len(domain.get_paths()) == 6
    x = np.linspace(sc3.x0, [0.82, 0.82, 0.82], 11)
    x[3:8, 1] += 0.3
    path = bn.BeliefPath.from_sensing(x, sc3.P0, np.broadcast_to(1e4 * np.eye(3), (10, 3, 3)), W=sc3.W)
    fig, ax = bp.plot_belief_path(sc3, path, title=True)
    tree = SimpleNamespace(x=x, parent=np.arange(-1, 10))
    bp.plot_tree(sc3, tree, ax=ax, show_scenario=False, path=path)
    fig.canvas.draw()
    assert len(bp.find_artists(ax, "tree-edges")[0].get_segments()) == 10
    _assert_real_image(bp.save_figure(fig, tmp_path / "cube.png", dpi=60))
    with pytest.raises(ValueError):
        bp.plot_scenario(sc3, ax=plt.subplots()[1])


@pytest.mark.parametrize("name, box", [("paper-multi", None), ("wide", ((0.0, 0.0), (2.0, 1.0))),
                                       ("tutorial", None)])
def test_legend_is_inside_a_plain_savefig_and_clear_of_the_axis_label(sc, tmp_path, name, box):
    """plot_belief_path(legend=True) then a plain fig.savefig: the legend lies
    inside the saved figure and does not overlap the x-axis label or the axes,
    on square and on wide maps."""
    if box is None:
        scen = bn.load_scenario(name)
    else:
        scen = bn.scenario_from_dict({"name": name, "domain": {"box": {"lower": list(box[0]), "upper": list(box[1])}},
                                      "target": {"box": {"lower": [1.8, 0.8], "upper": [1.95, 0.95]}},
                                      "start": {"x": [0.1, 0.1], "P": [[1e-9, 0], [0, 1e-9]]},
                                      "noise": {"W": [[2e-4, 0], [0, 2e-4]]}, "obstacles": []})
    x = np.linspace(scen.x0, scen.x0 + 0.05, 4)
    path = bn.BeliefPath.from_sensing(x, scen.P0, np.zeros((3, 2, 2)), W=scen.W)
    fig, ax = bp.plot_belief_path(scen, path, title=True, legend=True)
    ax.set_xlabel("x (m)")
    fig.savefig(tmp_path / "a.png")                    # plain: no bbox_inches
    r = fig.canvas.get_renderer()
    leg = ax.get_legend().get_window_extent(r)
    fb = fig.bbox
    assert fb.x0 - 1 <= leg.x0 and leg.x1 <= fb.x1 + 1 and fb.y0 - 1 <= leg.y0 and leg.y1 <= fb.y1 + 1
    assert not leg.overlaps(ax.xaxis.label.get_window_extent(r))
    assert not leg.overlaps(ax.get_window_extent(r))
