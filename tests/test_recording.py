"""sweeps/estimate_recording.py and armimp_jax.study.recording (recording, estimate_recording): a simulated
trial through CSV, NPZ and MAT-files gives the library's numbers; every bad recording gets its own one-line message."""

import importlib.util
import json
import pathlib
import re
import subprocess
import sys

import jax
import numpy as np
import pytest
from helpers import env_without_jax

import armimp_jax as aj
from armimp_jax import paper
from armimp_jax.study.recording import estimate_recording, recording

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "sweeps" / "estimate_recording.py"
_spec = importlib.util.spec_from_file_location("estimate_recording", SCRIPT)
script = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(script)

WELCH = dict(nperseg=1024, noverlap=768, nfft=1280, window=("tukey", 0.25), fmax=15.0)
ARGS = ["--fs", "1000", "--nperseg", "1024", "--noverlap", "768", "--nfft", "1280", "--window", "tukey,0.25"]
HEADER = ["time", "fh_y", "f_delta_x", "f_delta_y", "x", "y", "fh_x", "note"]  # shuffled, with extras


@pytest.fixture(scope="module")
def trial():
    """A 4.5 s frictionless PD trial at location 1 (10 substeps): f_delta, x, fh ``(N, 2)``."""
    fd = aj.perturbation(jax.random.PRNGKey(3), 4500, paper.perturbation_peak(1))
    sim = jax.jit(aj.simulate, static_argnames="numerics")(
        paper.trial("pd", 0, 1), fd, numerics=aj.Numerics(substeps=10)
    )
    return {"f_delta": np.asarray(fd), "x": np.asarray(sim.x), "fh": np.asarray(sim.fh)}


def _columns(rec):
    n = len(rec["x"])
    return {
        "time": np.arange(n) / 1000.0,
        "f_delta_x": rec["f_delta"][:, 0],
        "f_delta_y": rec["f_delta"][:, 1],
        "x": rec["x"][:, 0],
        "y": rec["x"][:, 1],
        "fh_x": rec["fh"][:, 0],
        "fh_y": rec["fh"][:, 1],
    }


def write_csv(path, rec, *, header=HEADER, rename=None, edit=None):
    """Write ``rec`` as CSV (round-trip exact floats); ``edit(rows)`` may spoil the cells."""
    cols = _columns(rec)
    rows = [[("ok" if h == "note" else repr(float(cols[h][k]))) for h in header] for k in range(len(rec["x"]))]
    if edit is not None:
        edit(rows)
    names = [(rename or {}).get(h, h) for h in header]
    path.write_text("\n".join(",".join(r) for r in [names, *rows]) + "\n")
    return path


@pytest.fixture(scope="module")
def reference(trial):
    """What the library gives for the trial: ``estimate`` (with its error model) then
    ``fit_impedance`` with the script's defaults (a fitted delay, spectral errors)."""
    est = aj.estimate(trial["f_delta"], trial["x"], trial["fh"], fs=1000.0, errors=True, **WELCH)
    return est, aj.fit_impedance(est, acquisition="delay", se="spectral")


def _strict(path):
    return json.loads(path.read_text(), parse_constant=lambda c: pytest.fail(f"not strict JSON: {c}"))


def test_csv_round_trip_gives_the_library_numbers(trial, reference, tmp_path, capsys):
    path = write_csv(tmp_path / "rec.csv", trial)
    out = tmp_path / "out"
    assert script.main([str(path), "--out", str(out), *ARGS]) == 0
    printed = capsys.readouterr().out
    est, fit = reference
    low, high = fit.interval("damping")
    for needle in (
        "95% intervals",
        f"damping xy [N s/m]: {float(fit.damping[0, 1]):10.4g}   95% [{low[0, 1]:.4g}, {high[0, 1]:.4g}]",
        "force-channel delay [ms]",
        "lack of fit",
        "coherence fh_y: min",
        "input coherence: max",
    ):
        assert needle in printed, needle
    assert "+-" not in printed  # no unlabelled standard errors
    result = _strict(out / "estimate.json")
    for name in ("mass", "damping", "stiffness", "mass_se", "damping_se", "stiffness_se", "dof"):
        np.testing.assert_allclose(result[name], getattr(fit, name), rtol=1e-9, err_msg=name)
    np.testing.assert_allclose(result["interval_95"]["damping"]["low"], low, rtol=1e-9)
    np.testing.assert_allclose(result["delay"]["value"], fit.delay, rtol=1e-9)
    np.testing.assert_allclose(result["lack_of_fit"]["p"], fit.lack_of_fit_p_overall, rtol=1e-9)
    # no --friction: unknown (the report's first line says so): only the record's stick-slip
    # could blame friction, and no warning blames friction that nobody said is there
    assert result["warnings"] == aj.spectra.fit_warnings(fit, est, acquisition="delay")
    assert not [w for w in result["warnings"] if w.startswith("instant force samples")]
    assert (
        printed.splitlines()[1] == "fit: acquisition 'delay' (robot friction unknown: stick-slip read from the record; "
        "--friction N_M if you know it)"
    )
    assert result["settings"]["friction_n_m"] is None
    assert f"verdict: {': '.join(estimate_recording.verdict(fit))}" in printed
    assert result["settings"]["acquisition"] == "delay" and result["settings"]["se"] == "spectral"
    np.testing.assert_allclose(result["vaf"]["per_element"], fit.vaf, rtol=1e-9)
    np.testing.assert_allclose(result["vaf"]["overall"], fit.vaf_overall, rtol=1e-9)
    assert result["settings"]["window"] == ["tukey", 0.25] and result["settings"]["nfft"] == 1280
    assert result["record"]["n_segments"] == (4500 - 768) // 256 and result["record"]["n_bins"] == len(est.f)
    cx = np.asarray(est.coh_multiple_x)
    np.testing.assert_allclose(result["coherence"]["multiple_x"]["y"]["min"], cx[:, 1].min(), rtol=1e-9)
    np.testing.assert_allclose(result["coherence"]["inputs_max"], np.max(est.coh_inputs), rtol=1e-9)
    with np.load(out / "estimate.npz") as npz:
        saved = dict(npz)
    for name, value in est._asdict().items():
        if name == "error":
            continue
        np.testing.assert_allclose(saved[name], value, rtol=1e-9, atol=1e-12 * np.abs(value).max(), err_msg=name)
    np.testing.assert_allclose(saved["Z_fit"], fit.impedance(est.f, acquisition="delay"), rtol=1e-9)
    np.testing.assert_allclose(saved["error_force"], est.error.force, rtol=1e-9)
    for fig in ("bode.png", "coherence.png"):
        assert (out / fig).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in out.iterdir()) == ["bode.png", "coherence.png", "estimate.json", "estimate.npz"]


def test_npz_layouts_and_renamed_columns_read_the_same_recording(trial, tmp_path):
    from_csv = recording.load_recording(write_csv(tmp_path / "rec.csv", trial))
    for name in ("f_delta", "x", "fh"):
        np.testing.assert_array_equal(from_csv[name], trial[name])  # repr floats round-trip exactly
    np.savez(tmp_path / "grouped.npz", **trial)
    np.savez(tmp_path / "columns.npz", **_columns(trial))
    rename = {"fh_x": "Fx", "fh_y": "Fy", "x": "pos x"}
    renamed = write_csv(tmp_path / "renamed.csv", trial, rename=rename)
    mapping = recording.parse_columns(" fh_x=Fx, fh_y=Fy,x=pos x")
    semicolons = tmp_path / "semi.csv"
    semicolons.write_text("# a comment line\n" + renamed.read_text().replace(",", ";"))
    for loaded in (
        recording.load_recording(tmp_path / "grouped.npz"),
        recording.load_recording(tmp_path / "columns.npz"),
        recording.load_recording(renamed, columns=mapping),
        recording.load_recording(semicolons, columns=mapping),
    ):
        for name in ("f_delta", "x", "fh"):
            np.testing.assert_array_equal(loaded[name], trial[name])


def _spoil(row, column, value):
    def edit(rows):
        rows[row][HEADER.index(column)] = value

    return edit


def _truncate(column, n):
    def edit(rows):
        for r in rows[-n:]:
            r[HEADER.index(column)] = ""

    return edit


CSV_CASES = {
    "missing column": (  # the command line's own option, not the library's columns=
        dict(header=[h for h in HEADER if h != "fh_y"]),
        [],
        r"missing column\(s\) 'fh_y'; found 'time'.*; name the file's columns with --columns fh_y=NAME$",
    ),
    "misnamed column": (
        dict(rename={"fh_x": "fhx"}),
        [],
        r"missing column\(s\) 'fh_x' \(did you mean 'fhx'\?\).* with --columns fh_x=fhx$",
    ),
    "non-numeric cell": (
        dict(edit=_spoil(9, "y", "abc")),
        [],
        r"row 10 \(line 11\), column 'y': 'abc' is not a number",
    ),
    "empty cell": (dict(edit=_spoil(99, "fh_x", "")), [], r"row 100 \(line 101\), column 'fh_x' is empty"),
    "NaN": (dict(edit=_spoil(41, "x", "nan")), [], r"row 42 \(line 43\), column 'x': nan is not finite"),
    "inf": (dict(edit=_spoil(4, "f_delta_y", "-inf")), [], r"row 5 \(line 6\), column 'f_delta_y': -inf is not finite"),
    "unequal lengths": (dict(edit=_truncate("y", 3)), [], r"unequal lengths \(values per column: .*x 4500, y 4497"),
    "too short": (dict(edit=lambda rows: rows.__delitem__(slice(1200, None))), [], r"1200 samples, which give 1 Welch"),
    "bad mapping": (dict(), ["--columns", "fh_x"], r"column mapping 'fh_x' is not STANDARD=NAME"),
    "unknown standard name": (dict(), ["--columns", "force=Fx"], r"unknown standard column\(s\) 'force'"),
    "zero sample rate": (dict(), ["--fs", "0"], r"--fs must be a finite sample rate > 0 Hz, got 0"),
    "negative sample rate": (dict(), ["--fs", "-1000"], r"--fs must be a finite sample rate > 0 Hz, got -1000"),
    "unknown window": (dict(), ["--window", "nope"], r"window 'nope' is not one scipy.signal.get_window knows"),
    "nfft below nperseg": (dict(), ["--nfft", "512"], r"nfft must be >= 1024, got 512"),
}


def _run_bad(path, extra, tmp_path, capsys):
    out = tmp_path / "out"
    code = script.main([str(path), "--out", str(out), *ARGS, *extra])
    err = capsys.readouterr().err
    assert code == 2
    assert not out.exists()  # refused before any work
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("estimate_recording: error: "), err
    return lines[0]


@pytest.mark.parametrize("case", CSV_CASES)
def test_bad_csv_recordings_get_their_message(case, trial, tmp_path, capsys):
    kwargs, extra, message = CSV_CASES[case]
    path = write_csv(tmp_path / "rec.csv", trial, **kwargs)
    line = _run_bad(path, extra, tmp_path, capsys)
    assert re.search(message, line), line


def _npz(path, **arrays):
    np.savez(path, **arrays)
    return path


def _bad_files(tmp_path, trial):
    cols = _columns(trial)
    nan = dict(cols, x=np.where(np.arange(len(cols["x"])) == 7, np.nan, cols["x"]))
    binary = tmp_path / "binary.csv"
    binary.write_bytes(b"\xff\xfe\x00\x81garbage")
    corrupt = tmp_path / "corrupt.npz"
    corrupt.write_bytes(b"PK\x03\x04 not really a zip")
    npy = tmp_path / "single.npz"
    with open(npy, "wb") as fh:
        np.save(fh, trial["x"])
    header_only = tmp_path / "header.csv"
    header_only.write_text(",".join(HEADER) + "\n\n")
    return {
        "nonexistent": (tmp_path / "nope.csv", r"cannot read .*nope.csv: it does not exist"),
        "folder": (tmp_path, r"cannot read .*: it is a folder"),
        "binary": (binary, r"not a UTF-8 text \(CSV\) file"),
        "corrupt npz": (corrupt, r"cannot read .*corrupt.npz as NPZ"),
        "npy as npz": (npy, r"cannot read .*single.npz as NPZ: not a zip archive"),
        "empty": (_write(tmp_path / "empty.csv", ""), r"no header row"),
        "header only": (header_only, r"the header is not followed by any data rows"),
        "npz text": (
            _npz(tmp_path / "npz_text.npz", **dict(cols, y=cols["y"].astype(str))),
            r"array 'y' is not real numbers",
        ),
        "npz NaN": (_npz(tmp_path / "npz_NaN.npz", **nan), r"array 'x', index 7: nan is not finite"),
        "npz lengths": (
            _npz(tmp_path / "npz_lengths.npz", **dict(cols, fh_x=cols["fh_x"][:-1])),
            r"unequal lengths .*fh_x 4499",
        ),
        "npz missing": (
            _npz(tmp_path / "npz_missing.npz", x=cols["x"]),
            r"missing array\(s\) 'f_delta_x'.* \(or give f_delta, x, fh",
        ),
        "npz shape": (
            _npz(tmp_path / "npz_shape.npz", f_delta=trial["f_delta"], x=cols["x"][:, None], fh=trial["fh"]),
            r"\(N, 2\)",
        ),
    }


def _write(path, text):
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "case",
    [
        "nonexistent",
        "folder",
        "binary",
        "corrupt npz",
        "npy as npz",
        "empty",
        "header only",
        "npz text",
        "npz NaN",
        "npz lengths",
        "npz missing",
        "npz shape",
    ],
)
def test_unreadable_and_bad_npz_recordings_get_their_message(case, trial, tmp_path, capsys):
    files = tmp_path / "files"
    files.mkdir()
    path, message = _bad_files(files, trial)[case]
    line = _run_bad(path, [], tmp_path, capsys)
    assert re.search(message, line), line
    with pytest.raises(recording.RecordingError, match=message):
        recording.load_recording(path)


def test_help_answers_before_jax_and_states_units_conventions_and_columns(tmp_path):
    env = env_without_jax(tmp_path)  # --help must not import JAX (test_scripts.py checks every script so)
    done = subprocess.run([sys.executable, str(SCRIPT), "--help"], capture_output=True, text=True, check=True, env=env)
    text = done.stdout
    for needle in ("[N]", "[m]", "[Hz]", "TO the hand", "RECEIVES", "-F_h", "frame", "f_delta_x, f_delta_y"):
        assert needle in text, needle
    for name in recording.COLUMNS:
        assert name in text


def test_json_is_strict_and_writes_leave_no_temporary_files(trial, tmp_path, capsys):
    """With --acquisition instant there is no delay: its dof is NaN, written as null."""
    out = tmp_path / "out"
    code = script.main(
        [str(write_csv(tmp_path / "rec.csv", trial)), "--out", str(out), *ARGS, "--acquisition", "instant"]
    )
    assert code == 0
    assert "force-channel delay" not in capsys.readouterr().out
    result = _strict(out / "estimate.json")
    assert result["delay"] == {"value": 0.0, "se": 0.0, "dof": None}
    assert result["settings"]["period_s"] == 1e-3
    assert sorted(p.name for p in out.iterdir()) == ["bode.png", "coherence.png", "estimate.json", "estimate.npz"]


def test_mat_files_give_the_same_estimate_as_csv(trial, tmp_path, capsys):
    """A MAT-file written by scipy.io.savemat (the six columns as row vectors, or f_delta,
    x, fh as (N, 2) matrices) gives bitwise the estimate.json of the same data in CSV."""
    import scipy.io

    runs = {}
    for name, path in (
        ("csv", write_csv(tmp_path / "rec.csv", trial)),
        ("columns", tmp_path / "columns.mat"),
        ("grouped", tmp_path / "grouped.mat"),
    ):
        if name == "columns":
            scipy.io.savemat(path, _columns(trial))
        elif name == "grouped":
            scipy.io.savemat(path, trial)
        out = tmp_path / f"out_{name}"
        assert script.main([str(path), "--out", str(out), *ARGS]) == 0
        runs[name] = _strict(out / "estimate.json")
        runs[name].pop("settings")
    capsys.readouterr()
    assert runs["columns"] == runs["csv"] and runs["grouped"] == runs["csv"]


def _mat_v73(path):
    """The first bytes of a MATLAB v7.3 file: a text header, then HDF5 at offset 512."""
    head = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
    path.write_bytes(head.ljust(128, b" ") + bytes(384) + b"\x89HDF\r\n\x1a\n" + bytes(64))
    return path


def test_bad_mat_files_get_their_message(trial, tmp_path, capsys):
    import scipy.io

    cols = _columns(trial)
    nan = dict(cols, fh_y=np.where(np.arange(len(cols["x"])) == 12, np.nan, cols["fh_y"]))
    scipy.io.savemat(tmp_path / "nan.mat", nan)
    scipy.io.savemat(tmp_path / "missing.mat", {k: v for k, v in cols.items() if k != "fh_x"})
    (tmp_path / "text.mat").write_text("not a mat file at all, just text that goes on for a while\n" * 4)
    cases = {
        "v73.mat": r"is a MATLAB v7.3 MAT-file: re-save it in MATLAB with save\(file, \.\.\., '-v7'\)",
        "nan.mat": r"array 'fh_y', index 12: nan is not finite",
        "missing.mat": r"missing array\(s\) 'fh_x'",
        "text.mat": r"cannot read .*text.mat as a MAT-file",
    }
    _mat_v73(tmp_path / "v73.mat")
    for name, message in cases.items():
        line = _run_bad(tmp_path / name, [], tmp_path, capsys)
        assert re.search(message, line), line
        assert line.count("\n") == 0


def test_friction_warning_fires_only_when_given_and_segments_follow_the_record(trial, tmp_path, capsys):
    """--friction above 0 (with delayed force samples, the default) is the warning's cause; the
    same run without Welch options takes segments that follow the record (welch_segments)."""
    path = write_csv(tmp_path / "rec.csv", trial)
    out = tmp_path / "out"
    assert script.main([str(path), "--fs", "1000", "--out", str(out), "--friction", "0.5"]) == 0
    printed = capsys.readouterr().out
    result = _strict(out / "estimate.json")
    said = [w for w in result["warnings"] if w.startswith("instant force samples through a robot with joint friction")]
    assert len(said) == 1 and f"WARNING: {said[0]}" in printed.splitlines()
    assert printed.splitlines()[1] == "fit: acquisition 'delay'"  # friction given: nothing assumed
    assert result["settings"]["friction_n_m"] == 0.5
    assert not any(w.startswith(("the file's time column", "implausible")) for w in result["warnings"])
    nperseg, noverlap = aj.spectra.welch_segments(len(trial["x"]))
    assert (result["settings"]["nperseg"], result["settings"]["noverlap"]) == (nperseg, noverlap)
    assert nperseg < 4500 // 2  # not Table 4's 8192, which a 4.5 s record cannot hold twice
    assert result["record"]["n_segments"] == (len(trial["x"]) - noverlap) // (nperseg - noverlap)


def test_missing_columns_name_the_library_mapping_or_the_command_line_option(trial, tmp_path):
    path = write_csv(tmp_path / "rec.csv", trial, rename={"fh_x": "fhx"})
    with pytest.raises(recording.MissingColumnsError) as err:
        recording.load_recording(path)
    assert str(err.value).endswith("name the file's columns with columns={'fh_x': 'fhx'}")
    assert err.value.for_option("--columns").endswith("name the file's columns with --columns fh_x=fhx")
    np.savez(tmp_path / "rec.npz", **{k: v for k, v in _columns(trial).items() if k != "y"})
    with pytest.raises(recording.MissingColumnsError, match=r"arrays with columns=\{'y': 'NAME'\} \(or give"):
        recording.load_recording(tmp_path / "rec.npz")


def _noisy_z(seed: int = 0):
    """A second-order ``Z`` (negative stiffness on the diagonal: its phase starts at 180 deg) and
    an estimate of it whose phase noise crosses the branch cut again and again."""
    f = np.geomspace(0.1, 15.0, 150)
    s = 2j * np.pi * f[:, None, None]
    z_fit = np.array([[1.5, -0.6], [-0.6, 1.0]]) * s**2 + 10.0 * s + np.array([[-300.0, 80.0], [80.0, 250.0]])
    rng = np.random.default_rng(seed)
    return f, z_fit, z_fit * np.exp(1j * rng.uniform(-2.8, 2.8, z_fit.shape))


def test_bode_phase_of_a_noisy_estimate_stays_on_the_models_branch():
    from armimp_jax.study.recording import recording_figures as rf

    f, z_fit, z = _noisy_z()
    unwrapped = np.degrees(np.unwrap(np.angle(z), axis=0))
    model = np.degrees(np.unwrap(np.angle(z_fit), axis=0))
    assert np.abs(unwrapped - model).max() > 360.0  # what the old plot drew: whole turns of drift
    near = rf.phase_near(z, z_fit)
    assert np.abs(near - model).max() <= 180.0 + 1e-9
    np.testing.assert_allclose(np.exp(1j * np.radians(near)), z / np.abs(z), atol=1e-12)  # the same angle
    fig = rf.bode_figure(f, z, z_fit, title="a title")
    assert fig._suptitle.get_text() == "a title"
    for col, (i, j) in enumerate(rf.ELEMENTS):
        estimate, fitted = fig.axes[4 + col].get_lines()
        np.testing.assert_allclose(estimate.get_ydata(), near[:, i, j])
        np.testing.assert_allclose(fitted.get_ydata(), model[:, i, j])


def test_verdict_reads_lack_of_fit_and_vaf_together():
    import types

    def fit(vaf, p):
        return types.SimpleNamespace(vaf_overall=vaf, lack_of_fit_p_overall=p)

    headline, why = estimate_recording.verdict(
        fit(7.8, 0.47)
    )  # the newcomer's kind: a low VAF, a lack-of-fit ratio about 1
    assert headline.startswith("no evidence against the model at this noise") and "noisy estimate" in headline
    assert "the person's own force below 2 Hz included, is much of Z" in why
    # a perturbation in few bins (a multisine's lines): the classical route cannot tell, and says why
    headline, why = estimate_recording.verdict(fit(4.8, 0.5), share=0.09)
    assert headline.startswith("the classical route cannot tell from these bins") and "9%" in headline
    assert "the person's own force (below 2 Hz)" in why and "--lines" in why and "--model" in why
    headline, _ = estimate_recording.verdict(fit(99.0, 0.5), share=0.09, lines=True)
    assert headline.startswith("the model describes Z (the 9% of the bins that hold the perturbation's lines)")
    assert estimate_recording.verdict(fit(99.7, 0.85))[0].startswith(
        "the model describes Z within the estimate's noise"
    )
    for vaf in (99.7, 7.8):  # a significant lack of fit is a misfit, whatever the VAF
        assert estimate_recording.verdict(fit(vaf, 1e-6))[0].startswith("the model does not describe Z")
    assert estimate_recording.verdict(fit(50.0, float("nan")))[0] == "no lack-of-fit test"


def test_the_classical_route_on_a_designed_multisine_says_why_and_fits_at_its_lines():
    """A lab's day: one 48 s recording of IMBIC with 1 N m of Coulomb friction, the person's own
    force and the design's kind of signal (16 log-spaced multisine lines, 0.66 N RMS, 2.25 N
    peak). Fitted over every Welch bin the classical route cannot tell (its lines fill few
    bins: the rest are the person's force and noise) and says so; fitted at the bins that hold
    the lines (--lines), every diagonal of M, B, K lies in its 95% interval."""
    arm = paper.arm(2)
    noise = dict(sensors=aj.Sensors(force_noise=0.05, encoder_counts=2**18), voluntary=aj.VoluntaryForce(0.3, 2.0))
    trial = aj.make_trial(aj.IMBIC(), arm=arm, friction=aj.LuGre(1.0, 1.5), **noise)
    family = aj.signals.multisine(np.geomspace(0.1, 15.0, 16), 1.0, offset=0.5)
    limits = aj.experiment.Limits(rms_force=0.66, peak_force=2.25, record=48.0)
    f = np.asarray(aj.signals.limited_signal(family, limits, key=jax.random.key(0)))
    sim = jax.jit(aj.simulate, static_argnames="numerics")(
        trial, f, key=jax.random.key(7), numerics=aj.solvers.IDENTIFY_NUMERICS
    )
    rec = dict(f_delta=f, x=np.asarray(sim.x), fh=np.asarray(sim.fh))
    welch, _, _ = estimate_recording.route_settings(f.shape[0], fs=1000.0)
    holds, share = estimate_recording.input_bins(f, welch)
    assert share < estimate_recording.SPARSE_SHARE, (share, holds.sum())
    _, every = estimate_recording.analyse(rec, fs=1000.0)
    headline, why = estimate_recording.verdict(every, share=share)
    assert headline.startswith("the classical route cannot tell") and "person's own force (below 2 Hz)" in why
    _, at_lines = estimate_recording.analyse(rec, fs=1000.0, lines=True)
    assert float(at_lines.vaf_overall) > 90.0
    for name in ("mass", "damping", "stiffness"):
        low, high = at_lines.interval(name)
        true = np.asarray(getattr(arm, name))
        for i in (0, 1):
            assert low[i, i] <= true[i, i] <= high[i, i], (name, i, low[i, i], high[i, i], true[i, i])


def test_the_files_own_clock_and_a_flipped_force_are_warned_of(trial, tmp_path, capsys):
    """A file whose time column says 250 Hz, given --fs 1000, and whose force was recorded as the
    force the hand exerts (-F_h): the clock's disagreement, then the fit's negative M and K with
    the force's sign named first (the programs of the test above: the record's shapes)."""
    path = write_csv(tmp_path / "rec.csv", dict(trial, fh=-trial["fh"]))
    text = path.read_text().splitlines()
    times = [repr(k / 250.0) for k in range(len(trial["x"]))]
    path.write_text("\n".join([text[0], *(f"{t},{row.split(',', 1)[1]}" for t, row in zip(times, text[1:]))]) + "\n")
    assert script.main([str(path), "--fs", "1000", "--out", str(tmp_path / "out")]) == 0
    printed = capsys.readouterr().out.splitlines()
    clock, fit = _strict(tmp_path / "out" / "estimate.json")["warnings"][:2]
    assert clock.startswith("the file's time column steps by 0.004 s (median): a rate of 250 Hz, but fs is 1000 Hz")
    assert fit.startswith("implausible for a human arm: Mxx -1.5") and "Kyy -2" in fit
    assert fit.split("most likely first: ")[1].startswith("the force's sign")
    assert f"WARNING: {clock}" in printed and f"WARNING: {fit}" in printed


@pytest.mark.slow  # about a minute cold: the estimate and fit compile again for the 4 times as many bins
def test_a_rate_given_too_low_is_warned_of_by_the_files_clock_and_the_fit(trial, tmp_path, capsys):
    """The lab's day: --fs 250 on a 1 kHz file with a time column. The fit reads bins beyond the
    perturbation's band and goes negative; the clock, then the fit with the sample rate first."""
    path = write_csv(tmp_path / "rec.csv", trial)
    assert script.main([str(path), "--fs", "250", "--out", str(tmp_path / "out")]) == 0
    clock, fit = _strict(tmp_path / "out" / "estimate.json")["warnings"][:2]
    assert clock.startswith("the file's time column steps by 0.001 s (median): a rate of 1000 Hz, but fs is 250 Hz")
    assert fit.startswith("implausible for a human arm: Mxx -1.6") and "Kxx -2.144e+04 N/m (negative)" in fit
    assert fit.split("most likely first: ")[1].startswith("the sample rate")


def test_a_time_column_is_read_when_there_and_its_steps_checked_against_the_rate(trial, tmp_path):
    """The time column (``time``, ``Time``, ..., ``t``, or mapped) comes back as ``"time"``;
    seconds or milliseconds at the rate given say nothing, another rate, a clock that does not run
    forward and dropped samples a line each; a file without one, nothing."""
    n = len(trial["x"])
    rec = recording.load_recording(write_csv(tmp_path / "rec.csv", trial))
    np.testing.assert_array_equal(rec["time"], np.arange(n) / 1000.0)
    assert recording.timestamp_warnings(rec, 1000.0) == []
    cols = {k: v for k, v in _columns(trial).items() if k != "time"}
    np.savez(tmp_path / "t.npz", t=np.arange(n) * 1.0, T=np.zeros(n), **cols)  # a millisecond clock "t"; "T" a torque
    assert recording.timestamp_warnings(recording.load_recording(tmp_path / "t.npz"), 1000.0) == []
    np.savez(tmp_path / "clock.npz", clock=np.arange(n) / 500.0, **cols)
    assert "time" not in recording.load_recording(tmp_path / "clock.npz")  # not a time column's name
    mapped = recording.load_recording(tmp_path / "clock.npz", columns={"time": "clock"})
    (line,) = recording.timestamp_warnings(mapped, 1000.0)
    assert line.startswith("the file's time column steps by 0.002 s (median): a rate of 500 Hz, but fs is 1000 Hz")
    with pytest.raises(recording.MissingColumnsError, match=r"missing array\(s\) 'stamp' \(for time\)"):
        recording.load_recording(tmp_path / "clock.npz", columns={"time": "stamp"})
    gaps = np.arange(n) / 1000.0
    gaps[100:] += 0.005  # five samples dropped
    (line,) = recording.timestamp_warnings({"time": gaps}, 1000.0)
    assert line.startswith("the file's time column is uneven: steps from 0.001 to 0.006")
    assert "does not run forward" in recording.timestamp_warnings({"time": np.zeros(n)}, 1000.0)[0]
    assert recording.timestamp_warnings(cols, 1000.0) == []
