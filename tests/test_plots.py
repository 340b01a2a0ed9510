"""The reproduction's figures from synthetic results: error bars and bands only with several
seeds, bars from zero on linear axes, continuous phase, the worst coherence shown, PD as
IMBIC's reference, words for labels."""

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from armimp_jax.paper import plots  # noqa: E402
from armimp_jax.paper.claims import mean_ci  # noqa: E402
from armimp_jax.presets._paper import arm  # noqa: E402

F = np.linspace(1.0, 15.0, 15)


def _metrics(phi, coh_min):
    return dict(
        phi_T=phi,
        phi_ij=[[phi / 2, phi / 4], [phi / 4, phi / 2]],
        coh_multiple_x_min_low=coh_min,
        coh_multiple_x_min_high=0.99,
    )


def _arrays(location, friction, seed, coh_min):
    # a phase that runs past +-180 deg, as friction-afflicted estimates do
    z = np.asarray(arm(location).impedance(F)) * np.exp(-1j * np.radians(40.0 * (1 + friction)) * F)[:, None, None]
    coh = np.clip(np.linspace(coh_min, 1.0, F.size) + 0.01 * seed, 0, 1)
    return dict(
        f=F,
        Z=z * (1 + 0.05 * seed),
        coh_multiple_x=np.stack([coh, coh], -1),
        coh_partial_x=np.stack([np.stack([coh, coh], -1)] * 2, -2),
    )


def synthetic(seeds: int):
    """Results and arrays shaped like ``reproduce.aggregate``'s: PD at location 1 over three
    perturbation levels, IMBIC at four locations (worst coherence at location 4)."""
    cells = [("pd", 1, p) for p in (1, 2, 3)] + [("imbic", loc, 1) for loc in (1, 2, 3, 4)]
    trials, conditions, arrays = [], [], {}
    for acq in ("instant", "interval_mean"):
        for e, loc, p in cells:
            for fr in (0, 1, 2):
                cond = dict(experiment=e, controller=e, location=loc, friction=fr, perturbation=p, acquisition=acq)
                phi = (300.0 if e == "imbic" else 400.0) * (1 + (fr if e == "imbic" else 5 * fr))
                coh_min = 0.3 if (e, loc, fr) == ("imbic", 4, 2) else 0.8
                metrics = []
                for s in range(seeds):
                    tid = f"{e}-L{loc}-F{fr}-P{p}-{acq}-s{s}"
                    m = _metrics(phi * (1 + 0.1 * s), coh_min)
                    trials.append(dict(id=tid, condition=cond, seed=s, diverged=False, metrics=m))
                    arrays[tid] = _arrays(loc, fr, s, coh_min)
                    metrics.append(m)
                stats = dict(condition=cond, n=seeds)
                for k in metrics[0]:
                    mean, sd, half = mean_ci([m[k] for m in metrics])
                    stats[k] = np.asarray(mean).tolist()
                    stats[k + "_sd"] = np.asarray(sd).tolist()
                    stats[k + "_ci"] = None if half is None else np.asarray(half).tolist()
                conditions.append(stats)
    return dict(trials=trials, conditions=conditions), arrays


@pytest.fixture
def figures(monkeypatch):
    """The figures each plotting function drew, kept open for inspection."""
    drawn = []

    def keep(fig, path):
        drawn.append(fig)
        return path

    monkeypatch.setattr(plots, "_save", keep)
    yield drawn
    plt.close("all")


def _error_bars(fig):
    return [c for ax in fig.axes for c in ax.containers if getattr(c, "errorbar", None) is not None]


def _bands(fig):
    return [c for ax in fig.axes for c in ax.collections if isinstance(c, matplotlib.collections.PolyCollection)]


@pytest.mark.parametrize("seeds", [1, 3])
def test_intervals_only_with_several_seeds(seeds, figures, tmp_path):
    results, arrays = synthetic(seeds)
    for experiment in ("pd", "imbic"):
        plots.phi_bars(results, tmp_path / "phi.png", experiment=experiment)
        plots.bode_figure(results, arrays, tmp_path / "bode.png", experiment=experiment)
        plots.coherence_figure(results, arrays, tmp_path / "coh.png", experiment=experiment)
    plots.ablation_figure(results, tmp_path / "ablation.png")
    bars = [figures[0], figures[3], figures[6]]
    curves = [figures[1], figures[2], figures[4], figures[5]]
    if seeds == 1:
        assert not any(_error_bars(f) for f in bars) and not any(_bands(f) for f in curves)
        assert all("1 seed: no" in f._suptitle.get_text() for f in figures[:6])
    else:
        assert all(_error_bars(f) for f in bars) and all(_bands(f) for f in curves)
        assert all("mean of 3 seeds" in f._suptitle.get_text() for f in figures[:6])


def test_bars_start_from_zero_on_linear_axes_with_pd_as_imbic_reference(figures, tmp_path):
    results, _ = synthetic(3)
    plots.phi_bars(results, tmp_path / "phi.png", experiment="imbic")
    plots.ablation_figure(results, tmp_path / "ablation.png")
    fig9, ablation = figures
    for ax in fig9.axes:
        assert ax.get_yscale() == "linear" and ax.get_ylim()[0] == 0
        assert [t.get_text() for t in ax.get_xticklabels()][0].startswith("PD")
    heights = sorted(p.get_height() for p in fig9.axes[0].patches)
    assert heights[-1] == pytest.approx(400 * 11 * 1.1)  # PD, friction 2 (mean over seeds 1, 1.1, 1.2)
    # IMBIC at friction 2 is 3x its frictionless error, PD 11x: the ratio row says so
    ratios = [p.get_height() for p in fig9.axes[5].patches]
    assert pytest.approx(3.0) in ratios and pytest.approx(11.0) in ratios
    assert ablation.axes[0].get_xscale() == "linear" and ablation.axes[0].get_xlim()[0] == 0
    labels = [t.get_text() for t in ablation.axes[0].get_yticklabels()]
    assert "IMBIC, friction 2, location 4, perturbation 1" in labels
    assert all(t.get_rotation() == 0 for t in ablation.axes[0].get_yticklabels())


def _phase_error_lines(fig, color):
    """``(f, y)`` of the phase-error curves of ``color`` in the bottom row of a Bode figure."""
    out = []
    for ax in fig.axes[4:8]:
        out += [(line.get_xdata(), line.get_ydata()) for line in ax.get_lines() if line.get_color() == color]
    return out


def test_phase_is_the_phase_error_on_the_truths_branch(figures, tmp_path):
    """An estimate whose unwrapped phase slides a whole turn away from the truth, though its
    error is 0 at both ends, is drawn at 0 there, not 360 deg off; errors stay within +-180."""
    results, arrays = synthetic(1)
    turn = np.interp(np.arange(F.size), [0, 4, 8, F.size - 1], [0.0, 0.0, -360.0, -360.0])  # [deg]
    truth = np.asarray(arm(1).impedance(F))
    arrays["pd-L1-F2-P1-instant-s0"]["Z"] = truth * np.exp(1j * np.radians(turn))[:, None, None]
    plots.bode_figure(results, arrays, tmp_path / "bode.png", experiment="pd")
    (fig,) = figures
    assert "phase error" in fig.axes[4].get_ylabel()
    expected = (turn + 180.0) % 360.0 - 180.0
    for f, y in _phase_error_lines(fig, plots.FRICTION_COLORS[2]):
        drawn = ~np.isnan(y)
        np.testing.assert_allclose(y[drawn], expected[np.searchsorted(F, f[drawn])], atol=1e-9)
        assert np.all(np.abs(y[drawn]) <= 180.0)
        assert y[0] == pytest.approx(0.0) and y[-1] == pytest.approx(0.0, abs=1e-9)
    wrapped = np.degrees(np.angle(arrays["pd-L1-F1-P1-instant-s0"]["Z"][:, 0, 0]))
    assert np.any(np.abs(np.diff(wrapped)) > 180)  # the other curves' phases do wrap
    for f, y in _phase_error_lines(fig, plots.FRICTION_COLORS[1]):
        step = np.diff(y)  # NaN across the breaks inserted where the error crosses +-180 deg
        assert np.isnan(step).any() and np.all(np.abs(step[~np.isnan(step)]) < 180)  # no vertical strokes


def test_seeds_either_side_of_180_degrees_average_to_180_not_0(figures, tmp_path):
    results, arrays = synthetic(2)
    truth = np.asarray(arm(1).impedance(F))
    for seed, err in ((0, 179.0), (1, -179.0)):
        arrays[f"pd-L1-F2-P1-instant-s{seed}"]["Z"] = truth * np.exp(1j * np.radians(err))
    plots.bode_figure(results, arrays, tmp_path / "bode.png", experiment="pd")
    for _, y in _phase_error_lines(figures[0], plots.FRICTION_COLORS[2]):
        np.testing.assert_allclose(np.abs(y), 180.0, atol=1e-9)


@pytest.mark.slow  # about 12 s cold: every figure's layout
def test_titles_fit_and_legends_cover_no_data(monkeypatch, tmp_path):
    """Every figure as saved: no text beyond the figure's edges, no legend over a plot area."""
    kept, close = [], plt.close
    monkeypatch.setattr(plt, "close", lambda fig=None: kept.append(fig))
    results, arrays = synthetic(3)
    paths = plots.all_figures(results, arrays, tmp_path)
    assert len(kept) == len(paths) == 7
    for fig in kept:
        fig.canvas.draw()  # at the figure's own dpi, as its bbox is
        renderer = fig.canvas.get_renderer()
        edge = fig.bbox
        texts = [fig._suptitle] + [t for ax in fig.axes for t in (ax.title, ax.xaxis.label, ax.yaxis.label)]
        legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]
        assert legends, fig._suptitle.get_text()
        texts += [t for leg in legends for t in leg.get_texts()]
        for t in texts:
            if t is None or not t.get_text() or not t.get_visible():
                continue
            box = t.get_window_extent(renderer)
            assert edge.x0 - 1 <= box.x0 and box.x1 <= edge.x1 + 1, t.get_text()
            assert edge.y0 - 1 <= box.y0 and box.y1 <= edge.y1 + 1, t.get_text()
        for leg in legends:
            box = leg.get_window_extent(renderer)
            assert edge.x0 - 1 <= box.x0 and box.x1 <= edge.x1 + 1
            assert not any(box.overlaps(ax.bbox) for ax in fig.axes), [t.get_text() for t in leg.get_texts()]
        close(fig)


def test_coherence_shows_the_worst_location(figures, tmp_path):
    results, arrays = synthetic(3)
    assert plots.worst_cell(results, "imbic")[:2] == (4, 1)
    plots.coherence_figure(results, arrays, tmp_path / "coh.png", experiment="imbic")
    (fig,) = figures
    title = fig._suptitle.get_text()
    assert "location 4" in title and "lowest minimum multiple coherence (friction 2: 0.30" in title
    assert all(ax.get_ylabel().startswith("coherence") for ax in fig.axes[::3])
    legend = next(ax.get_legend() for ax in fig.axes if ax.get_legend() is not None)
    assert any("PD" in t.get_text() for t in legend.get_texts())
