"""A lab's day for a movement (``sweeps/movement.py``, ``study.recording.movement_day``, docs/movement.md): the
base case's config builds the base case's trial, a bad value is refused in one line naming it, the
script's table holds ``estimate_ensemble``'s numbers (simulated and from a lab's files), and the
stiffness ellipses are drawn along ``K``'s eigenvectors at the stated scale."""

import dataclasses
import importlib.util
import json
import pathlib
import types

import jax
import matplotlib.image
import numpy as np
import pandas as pd
import pytest
from helpers import tree_allclose

import armimp_jax as aj
from armimp_bench import movement as bench
from armimp_jax.study.recording import movement_day as day
from armimp_jax.study.recording import movement_figures as mf
from armimp_jax.study.schema.config import ConfigError

ROOT = pathlib.Path(__file__).resolve().parents[1]
BASE = ROOT / "sweeps" / "configs" / "movement_base.toml"
_spec = importlib.util.spec_from_file_location("movement_script", ROOT / "sweeps" / "movement.py")
script = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(script)
REPETITIONS = 25  # the fewest a round number above 4 J + 3 = 23 for five knots


def _config(tmp_path, old: str = "", new: str = "", name: str = "day.toml") -> pathlib.Path:
    """The base config with ``REPETITIONS`` reaches and ``old`` replaced by ``new``, in ``tmp_path``."""
    text = BASE.read_text().replace("repetitions = 50", f"repetitions = {REPETITIONS}")
    assert old in text
    path = tmp_path / name
    path.write_text(text.replace(old, new))
    return path


def test_the_base_config_builds_the_base_case():
    config = day.read_movement_config(BASE)
    trial = day.movement_trial(config, where=str(BASE))
    base = bench.base_trial()
    assert jax.tree.structure(trial) == jax.tree.structure(base)
    assert tree_allclose(trial, base, rtol=1e-12)
    plan = day.plan_reaches(config, trial)  # the hook: today the config's
    assert plan.repetitions == 50 and np.array_equal(plan.perturbation.peak, [bench.PEAK, bench.PEAK])
    assert np.allclose(config["profile"]["knots"], bench.KNOTS)
    assert config["estimate"] == dict(window=0.1, cutoff=30.0, acquisition="instant")


@pytest.mark.parametrize(
    "old, new, named",
    [
        ("repetitions = 25", "repetitions = 10", "[ensemble] repetitions = 10"),
        ("repetitions = 25", "repetitions = 1", "[ensemble] repetitions must be an integer >= 2"),
        ("[1.0, 0.7, 0.4, 0.7, 1.0]", "[1.0, 0.7, 0.4]", "[profile] stiffness_scale"),
        ("[0.4, 0.6, 0.8, 1.0, 1.2]", "[0.4, 0.8, 0.6, 1.0, 1.2]", "[profile] knots"),
        ("duration = 0.8", "duration = 1.4", "[reach] needs onset >= 0"),
        ("[estimate]", '[identify]\nroute = "models"\n\n[estimate]', "[identify] route"),
        ("level = 1", "level = 1\npeak = 2.0", "[perturbation] give level"),
        ("level = 1", "level = 4", "[perturbation] level must be one of the paper's 1-3, got 4"),
        ("record = 1.6", "record = 1.1", "[reach] needs onset >= 0"),
        ("1.0, 1.2]           #", "1.0, 1.7]           #", "[profile] knots [s] must lie in the record"),
        ("location = 3", "location = 7", "[arm] unknown arm location 7"),
        ("window = 0.1", "widow = 0.1", "[estimate] unknown key 'widow'"),
        ("[estimate]  ", "[plan]\nprecision = 10\n\n[estimate]  ", "[plan] precision must lie in (0, 1)"),
        ("# files = [", 'columns = ["fh_x"]\n# files = [', "[ensemble] columns: column mapping 'fh_x'"),
    ],
)
def test_a_bad_value_is_refused_in_one_line_naming_it(tmp_path, capsys, old, new, named):
    path = _config(tmp_path, old, new)
    with pytest.raises(SystemExit) as stop:
        script.main([str(path), "--out", str(tmp_path / "out")])
    assert stop.value.code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("movement: error: ") and named in lines[0], lines
    assert str(path) in lines[0]
    assert not (tmp_path / "out").exists()


def test_a_simulated_day_needs_its_sections(tmp_path):
    path = _config(tmp_path, '[controller]\ntype = "pd"', "")
    config = day.read_movement_config(path)
    with pytest.raises(ConfigError, match=r"missing section \[controller\]"):
        day.movement_trial(config, where=str(path))


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    """The script's day on the base case at ``REPETITIONS`` reaches, and the same ensemble again."""
    folder = tmp_path_factory.mktemp("day")
    path = _config(folder)
    assert script.main([str(path), "--out", str(folder / "out")]) == 0
    config = day.read_movement_config(path)
    trial = day.movement_trial(config)
    ens = day.gather(config, path, trial=trial, plan=day.plan_reaches(config, trial))
    return folder, ens, trial, config["profile"]["knots"]


def _written(out: pathlib.Path) -> tuple[pd.DataFrame, dict]:
    table = pd.read_csv(out / "movement.csv")

    def refuse(token):
        raise ValueError(f"not strict JSON: {token}")

    doc = json.loads((out / "movement.json").read_text(), parse_constant=refuse)
    return table, doc


def _same_numbers(table: pd.DataFrame, fit) -> None:
    expected = fit.table(0.95)
    assert list(table.columns) == list(day.COLUMNS)
    assert table[["parameter", "entry", "unit"]].astype(str).values.tolist() == (
        expected[["parameter", "entry", "unit"]].values.tolist()
    )
    for column in ("time", "value", "se", "low", "high"):
        np.testing.assert_array_equal(table[column].to_numpy(), expected[column].to_numpy(), err_msg=column)


def test_the_script_writes_estimate_ensemble_s_numbers_and_the_figures(simulated):
    folder, ens, trial, knots = simulated
    fit = aj.estimate_ensemble(ens, knots=knots)
    table, doc = _written(folder / "out")
    _same_numbers(table, fit)
    true = bench.truth(trial, knots)
    k = table[(table.parameter == "K") & (table.entry == "xy")]
    np.testing.assert_allclose(k.truth.to_numpy(), true["stiffness"][:, 0, 1], rtol=1e-12)
    assert [e["value"] for e in doc["entries"]] == table.value.tolist()
    assert doc["settings"]["simulated"] is True and doc["settings"]["armimp_jax"] == aj.__version__
    assert doc["ensemble"]["repetitions"] == REPETITIONS and doc["dof"] == REPETITIONS - 1
    assert any("only 25 repetitions" in w for w in doc["warnings"])
    for name in ("stiffness_ellipses.png", "impedance_time.png"):
        image = matplotlib.image.imread(folder / "out" / name)
        assert image.shape[:2] == (675, 1050), name  # 7 x 4.5 in at 150 dpi


def test_the_lab_s_files_give_the_same_numbers(simulated, tmp_path):
    """The simulated repetitions written as a lab's files (one NPZ each), listed in [ensemble] files."""
    _, ens, _, knots = simulated
    names = []
    for r in range(ens.repetitions):
        names.append(f"reach{r:02d}.npz")
        np.savez(tmp_path / names[-1], x=ens.x[r], fh=ens.fh[r], f_delta=ens.f_delta[r])
    path = _config(tmp_path, "# files = [", f"files = {json.dumps(names)}\n# [")
    assert script.main([str(path), "--out", str(tmp_path / "out")]) == 0
    table, doc = _written(tmp_path / "out")
    lab = aj.Ensemble(x=ens.x, fh=ens.fh, f_delta=ens.f_delta)
    _same_numbers(table, aj.estimate_ensemble(lab, knots=knots))
    assert table.truth.isna().all() and doc["settings"]["simulated"] is False


def _fit(stiffness) -> aj.results.EnsembleFit:
    """A fit with the knots' ``stiffness`` ``(J, 2, 2)``, no uncertainty."""
    j = len(stiffness)
    zeros = np.zeros((j, 2, 2))
    return aj.results.EnsembleFit(
        knots=np.arange(j) + 0.5,
        mass=np.eye(2),
        damping=zeros,
        stiffness=np.asarray(stiffness, dtype=float),
        mass_se=np.zeros((2, 2)),
        damping_se=zeros,
        stiffness_se=zeros,
        dof=20,
        covariance=np.zeros((2, 2 + 4 * j, 2 + 4 * j)),
        repetitions=21,
        window=0.1,
        cutoff=30.0,
        warnings=(),
    )


def test_the_ellipses_lie_along_k_s_eigenvectors_at_the_stated_scale():
    """Knot 0: K = diag(400, 100) N/m, its long axis along x; knot 1: the same turned by 30 deg (and
    made asymmetric: only the symmetric part counts). The hand moves 10 cm in y over 2 s."""
    turn = np.radians(30.0)
    rot = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    k0 = np.diag([400.0, 100.0])
    k1 = rot @ k0 @ rot.T + np.array([[0.0, 50.0], [-50.0, 0.0]])
    times = np.arange(2000) * 1e-3
    path = np.stack([np.zeros_like(times), 0.3 + 0.05 * times], axis=1)
    ens = types.SimpleNamespace(x=np.stack([path, path]), period=1e-3, times=times)
    fig = mf.path_figure(ens, _fit([k0, k1]))
    ax = fig.axes[0]
    scale = mf.SCALE_SHARE * 5.0 * times[-1] / 400.0  # [cm per N/m]: the stiffest semi-axis at SCALE_SHARE of the path
    for j, angle in ((0, 0.0), (1, turn)):
        (line,) = [ln for ln in ax.lines if ln.get_gid() == f"estimate-{j}"]
        xy = np.asarray(line.get_xydata())
        centre = 100.0 * np.array([0.0, 0.3 + 0.05 * (j + 0.5)])
        d = xy - centre
        r = np.hypot(d[:, 0], d[:, 1])
        major, minor = d[np.argmax(r)], d[np.argmin(r)]
        assert np.isclose(r.max(), 400.0 * scale, rtol=1e-4) and np.isclose(r.min(), 100.0 * scale, rtol=1e-3)
        u = major / r.max()
        assert abs(u[0] * np.sin(angle) - u[1] * np.cos(angle)) < 1e-3  # along the first eigenvector
        assert abs(np.dot(minor / r.min(), [np.cos(angle), np.sin(angle)])) < 2e-2  # across it
    texts = [t.get_text() for t in fig.findobj(lambda a: hasattr(a, "get_text"))]
    assert "200 N/m" in texts  # the scale bar, a round stiffness
    bar = [a for a in ax.artists if hasattr(a, "size_bar")][0]
    assert np.isclose(bar.size_bar.get_children()[0].get_width(), 200.0 * scale)


@pytest.mark.slow  # the model route over 25 reaches: about 2 minutes cold
def test_the_day_s_model_route_writes_identify_s_numbers(tmp_path):
    config = _config(tmp_path, "[estimate]", '[identify]\nroute = "model"\n\n[estimate]')
    ens, fit, paths = day.run_day(config, tmp_path / "out", echo=lambda *_: None)
    trial = day.movement_trial(day.read_movement_config(config), where=str(config))
    model_fit = aj.identify(trial, ens, free=("arm.mass", "arm.damping", "arm.stiffness"))
    written = pd.read_csv(tmp_path / "out" / "movement_model.csv")
    assert written["entry"].tolist() == model_fit.labels
    np.testing.assert_allclose(written["estimate"], model_fit.estimate, rtol=1e-9)
    np.testing.assert_allclose(written["se"], model_fit.se, rtol=1e-9)
    doc = json.loads((tmp_path / "out" / "movement_model.json").read_text())
    assert doc["converged"] and len(doc["entries"]) == len(model_fit.labels)
    assert np.all(np.abs((written["estimate"] - written["truth"]) / written["se"]) < 4.5)
    for name in ("stiffness_ellipses_model.png", "impedance_time_model.png"):  # its answer drawn as the classical
        assert matplotlib.image.imread(tmp_path / "out" / name).shape[:2] == (675, 1050), name


def _answer(knots, stiffness, damping, damping_knots=True) -> aj.results.EnsembleIdentification:
    """The model route's answer with ``stiffness`` at ``knots`` and ``damping`` there (or constant),
    a mass, and a covariance whose every entry is told apart (its SE from its place)."""
    labels, values = ["arm.mass[0,0]"], [2.0]
    for name, mats, at in (("damping", damping, damping_knots), ("stiffness", stiffness, True)):
        for j, m in enumerate(mats):
            where = f"@t={knots[j]:g}" if at else ""
            labels += [f"arm.{name}{where}[{a},{b}]" for a in range(2) for b in range(2)]
            values += list(np.ravel(m))
    n = len(labels)
    rng = np.random.default_rng(0)
    root = rng.normal(size=(n, 2))  # two common factors: the entries strongly correlated
    cov = root @ root.T + np.diag(np.arange(1, n + 1) * 0.05)
    estimate = np.asarray(values)
    return aj.results.EnsembleIdentification(
        labels=labels, estimate=estimate, se=np.sqrt(np.diag(cov)), start=estimate, covariance=cov,
        converged=True, steps=3, message="", noise_ratio=1.0, refreshed_step=0.0, spread_ratio=np.ones(n),
        check_refits=16, warnings=(), repetitions=40, seconds=1.0, settings={},
    )  # fmt: skip


def test_the_model_route_s_answer_is_drawn_on_its_knots(tmp_path):
    """``knot_view``: every knot's ``K`` and ``B`` the answer's own entries (a constant ``B`` repeated
    at each knot), their intervals ``interval``'s, each knot's ``K`` covariance the answer's block;
    the ellipses of the view are its ``K``'s; nothing to draw where ``B``'s knots are others."""
    knots = [0.4, 0.8]
    k = [np.array([[400.0, 20.0], [10.0, 100.0]]), np.array([[150.0, 0.0], [5.0, 300.0]])]
    b = [np.array([[12.0, 1.0], [0.5, 9.0]])]
    fit = _answer(knots, k, b, damping_knots=False)
    view = mf.knot_view(fit)
    np.testing.assert_array_equal(view.knots, knots)
    np.testing.assert_array_equal(view.stiffness, k)
    np.testing.assert_array_equal(view.damping, [b[0], b[0]])
    low, high = view.interval("stiffness")
    assert (low[1, 0, 1], high[1, 0, 1]) == fit.interval("arm.stiffness@t=0.8[0,1]")
    low, high = view.interval("damping", 0.9)
    assert (low[1, 1, 1], high[1, 1, 1]) == fit.interval("arm.damping[1,1]", 0.9)
    idx = [fit.labels.index(f"arm.stiffness@t=0.4[{a},{c}]") for a in range(2) for c in range(2)]
    np.testing.assert_array_equal(view.stiffness_covariance[0], fit.covariance[np.ix_(idx, idx)])
    draws = mf.stiffness_draws(view, n=20000)
    block = fit.covariance[np.ix_(idx, idx)]
    corr = block / np.sqrt(np.outer(np.diag(block), np.diag(block)))
    assert np.abs(corr[np.triu_indices(4, 1)]).max() > 0.5  # draws that ignored the correlations would fail
    np.testing.assert_allclose(np.corrcoef(draws[0].reshape(-1, 4).T), corr, atol=0.03)
    np.testing.assert_allclose(np.var(draws[0].reshape(-1, 4), axis=0), np.diag(block), rtol=0.05)
    times = np.arange(1200) * 1e-3
    path = np.stack([np.zeros_like(times), 0.3 + 0.1 * times], axis=1)
    ens = types.SimpleNamespace(x=np.stack([path, path]), period=1e-3, times=times)
    ax = mf.path_figure(ens, view).axes[0]
    (line,) = [ln for ln in ax.lines if ln.get_gid() == "estimate-1"]
    centre = 100.0 * np.array([0.0, 0.3 + 0.1 * 0.8])
    r = np.hypot(*(np.asarray(line.get_xydata()) - centre).T)
    low_k, high_k = np.linalg.eigvalsh(0.5 * (k[1] + k[1].T))
    assert np.isclose(r.max() / r.min(), high_k / low_k, rtol=1e-4)  # K at 0.8 s: its symmetric part's axes
    assert mf.profile_figure(ens, view).axes
    other = _answer(knots, k, [b[0], b[0]], damping_knots=True)
    assert mf.knot_view(other) is not None
    assert day.model_figures(tmp_path, ens, fit) and (tmp_path / "impedance_time_model.png").exists()
    lost = dataclasses.replace(fit, covariance=np.full_like(fit.covariance, np.nan), converged=False)
    assert day.model_figures(tmp_path / "lost", ens, lost) == []  # no intervals: nothing drawn, nothing raised
    shifted = _answer([0.4, 0.8], k, [b[0], b[0]])
    shifted.labels[1:5] = [lab.replace("@t=0.4", "@t=0.5") for lab in shifted.labels[1:5]]
    assert mf.knot_view(shifted) is None
