"""The figures' fixed layout (margins from the tick labels' characters, not
tight_layout's measuring): on awkward scales every label, title and offset text is
inside the figure and clear of the other axes."""

from __future__ import annotations

import numpy as np
import pytest

from tensorid.analysis.figures import compare_figure, convergence_figure, residual_figure

T = np.linspace(0.0, 10.0, 400)
SCALES = {
    "large, with an offset": 1e5 + 3 * np.sin(T),
    "tiny": 1e-9 * (2 + np.sin(T)),
    "wide and negative": -12345.6 + 3e4 * np.sin(T) ** 2,
    "small and negative": -0.00012 * np.sin(T),
}


def _texts(fig):
    """Every visible text of the figure's axes, with its box in pixels, after a draw."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()  # as savefig at the figure's dpi (100, as the files are written)
    renderer = canvas.get_renderer()
    out = []
    for ax in fig.axes:
        texts = [ax.title, ax.yaxis.label, ax.xaxis.label, ax.yaxis.get_offset_text()]
        texts += _drawn(ax.xaxis) + _drawn(ax.yaxis)
        out += [(ax, t, t.get_window_extent(renderer)) for t in texts if t.get_visible()]
    return out


def _drawn(axis):
    """The tick labels an axis draws: those of its major and minor ticks inside its
    view (a log axis within one decade labels its minor ticks)."""
    lo, hi = sorted(axis.get_view_interval())
    slack = 1e-9 * (hi - lo)
    ticks = axis.get_major_ticks() + axis.get_minor_ticks()
    return [t.label1 for t in ticks if lo - slack <= t.get_loc() <= hi + slack]


def _check(fig):
    texts = _texts(fig)
    width, height = fig.canvas.get_width_height()
    boxes = [(ax, ax.get_window_extent()) for ax in fig.axes]
    for ax, text, box in texts:
        if not text.get_text():
            continue
        assert box.x0 >= 0 and box.y0 >= 0, text.get_text()
        assert box.x1 <= width and box.y1 <= height, text.get_text()
        for other, frame in boxes:  # no text reaches into another axes' frame
            if other is not ax:
                assert not box.overlaps(frame), (text.get_text(), "overlaps another axes")


@pytest.mark.parametrize("name", SCALES)
def test_compare_figure_labels_fit_on_any_scale(name):
    y = SCALES[name]
    _check(compare_figure(T, y, y * 1.001, title=f"{name} (scored after the first 10 samples)"))


@pytest.mark.parametrize(
    "cost",
    [
        lambda i: -12345.67 + 100 * np.exp(-i),  # a likelihood: a linear axis
        lambda i: 1.16e-3 + 0.7e-3 * np.exp(-i),  # within one decade: minor labels
        lambda i: 4250 + 750 * np.exp(-i),
    ],
    ids=["negative", "within a decade", "large, within a decade"],
)
def test_convergence_figure_labels_fit_on_any_scale(cost):
    history = [{"iteration": i, "cost": cost(i), "grad_norm": 10.0 ** (-30 * i)} for i in range(9)]
    _check(convergence_figure(history, "newton: cost and gradient norm per iteration"))


def test_residual_figure_panels_keep_apart():
    lags = np.arange(26)
    panels = [
        dict(what="whiteness of y", passed=False, lags=lags, values=0.9**lags, feedback=None),
        dict(what="y against u", passed=True, lags=lags, values=-1e-4 * lags, feedback=lags[1:]),
    ]
    _check(residual_figure(0.08, panels))


def test_log_axes_are_labelled_in_plain_text():
    """No mathtext on the convergence figure's log axes (its parser was a third of the
    figure's time): "10⁻³" and, within a decade, "2×10⁻³", as Matplotlib would put them."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from tensorid.analysis.figures import plain_power

    assert plain_power(r"$\mathdefault{10^{-3}}$") == "10⁻³"
    assert plain_power(r"$\mathdefault{2\times10^{-3}}$") == "2×10⁻³"
    assert plain_power(r"$\mathdefault{10^{12}}$") == "10¹²"
    assert plain_power(r"$\mathdefault{1.5\times10^{-3}}$") == "1.5×10⁻³"
    for other in (r"$\mathdefault{10^{-2.5}}$", "0.5", "", r"$x^2$"):
        assert plain_power(other) == other
    history = [
        {"iteration": i, "cost": 1.16e-3 + 0.7e-3 * np.exp(-i), "grad_norm": 10.0**-i}
        for i in range(6)
    ]
    fig = convergence_figure(history, "t")
    FigureCanvasAgg(fig).draw()
    for ax in fig.axes:
        labels = [t.get_text() for t in ax.yaxis.get_ticklabels(which="both")]
        drawn = [s for s in labels if s]
        assert drawn and not any("$" in s for s in drawn)
        assert any("⁻" in s for s in drawn)


def test_the_legend_sits_between_the_title_and_the_data():
    """Above the axes, under the title, inside the figure: inside the axes it covered
    an oscillating record's peaks (compare and prediction figures)."""
    from tensorid.analysis.figures import prediction_figure

    y = np.sin(5 * T)
    long = "validation 'a-record-with-a-long-name', output y: GOF 0.9811"
    figs = [
        compare_figure(T, y, 0.98 * y, title=f"{long} (scored after the first 10 samples)"),
        prediction_figure(T, y, 0.98 * y, 0.99 * y, 0.02 + 0 * T, y, title=long, ylabel="y"),
    ]
    for fig in figs:
        _check(fig)
        ax = fig.axes[0]
        width, height = fig.canvas.get_width_height()
        frame, legend = ax.get_window_extent(), ax.get_legend().get_window_extent()
        title = ax.title.get_window_extent()
        assert legend.y0 >= frame.y1 - 1 and title.y0 >= legend.y1 - 2
        assert title.y1 <= height and legend.x1 <= width and legend.x0 >= 0
        assert not legend.overlaps(title)


def test_a_filters_huge_first_innovation_does_not_flatten_the_rest():
    """issue 51 item 7: an EKF's first innovation of −3e151 drew every other sample as
    a flat line at 0; the axes are the data's, the samples beyond them named."""
    from tensorid.analysis.figures import prediction_figure

    t = np.linspace(0, 10, 200)
    rng = np.random.default_rng(0)
    z = rng.standard_normal(200)
    z[0] = -3e151
    y = np.sin(t)
    pred = y.copy()
    pred[0] = -3e151
    fig = prediction_figure(t, y, y, pred, np.full(200, 0.1), z, title="t", ylabel="y")
    top, low = fig.axes
    assert top.get_ylim()[0] > -2 and top.get_ylim()[1] < 2
    assert 3 < low.get_ylim()[1] < 5
    (note,) = [x.get_text() for x in low.texts]
    assert note == "1 beyond the axis (largest -3e+151 at t = 0)"


def test_the_residual_tests_legend_covers_no_lag():
    """issue 51 item 9: the legend sat over the correlations of the largest lags."""
    from tensorid.analysis.figures import residual_figure

    rng = np.random.default_rng(0)
    panels = [
        dict(what="whiteness of y", passed=True, lags=np.arange(26),
             values=np.r_[1.0, 0.1 * rng.standard_normal(25)], feedback=None),
        dict(what="y against input u", passed=False, lags=np.arange(26),
             values=np.full(26, 0.6), feedback=0.6 * np.ones(25)),
    ]  # fmt: skip
    fig = residual_figure(0.14, panels)
    fig.canvas.draw()
    for ax, c in zip(fig.axes, panels, strict=True):
        box = ax.get_legend().get_window_extent()
        x = np.r_[c["lags"], [] if c["feedback"] is None else -np.arange(1, 26)]
        y = np.r_[c["values"], [] if c["feedback"] is None else c["feedback"]]
        points = ax.transData.transform(np.column_stack([x, y]))
        assert not any(box.contains(px, py) for px, py in points), c["what"]
