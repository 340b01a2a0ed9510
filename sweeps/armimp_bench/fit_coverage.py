"""What ``sweeps/bench_fit_coverage.py`` measures: whether the default fit's 95% intervals of
M, B, K hold the truth, and whether it warns when not (the script's docstring says how)."""

from __future__ import annotations

import time

CASES = (  # (controller, tau_c [N m]): the first three must cover, the rest must warn where they miss
    ("imbic", 0.0),
    ("imbic", 0.3),
    ("pd", 0.0),
    ("imbic", 1.0),
    ("imbic", 4.0),
    ("pd", 0.3),
    ("pd", 1.0),
)
FORCE_NOISE = 0.05  # [N]
LOCATION = 2  # paper arm
PARAMETERS = (("M", "mass"), ("B", "damping"), ("K", "stiffness"))


def fits_of(acquisition: str):
    """(label, fit_impedance keywords) of the three fits, for records of ``acquisition``."""
    return (
        ("defaults (delay / spectral)", dict()),
        (f"{acquisition} / spectral", dict(acquisition=acquisition)),
        ("textbook (plain / residual)", dict(acquisition="plain", se="residual")),
    )


_COMPILED = {}


def _compiled(*what):
    """The batch estimator (``"estimate"``) or fit (``acquisition, se``), compiled once."""
    if what not in _COMPILED:
        import jax

        import armimp_jax as aj

        if what == ("estimate",):
            fn = jax.vmap(lambda a, b, c: aj.estimate(a, b, c))
        else:
            fn = jax.vmap(lambda e: aj.fit_impedance(e, **dict(what)))
        _COMPILED[what] = jax.jit(fn)
    return _COMPILED[what]


def _warned(fits, n: int, tau_c: float):
    """Per trial: does ``fit.warnings`` say anything with the friction unknown, and when told?"""
    import jax
    import numpy as np

    import armimp_jax as aj

    one = [jax.tree.map(lambda a, i=i: a[i], fits) for i in range(n)]
    unknown = [bool(f.warnings) for f in one]
    told = [bool(aj.spectra.fit_warnings(f, friction=tau_c)) for f in one]
    return np.array(unknown), np.array(told)


def run_case(controller: str, tau_c: float, acquisition: str, f_delta, keys):
    import jax
    import numpy as np

    import armimp_jax as aj
    from armimp_jax import paper

    friction = aj.NO_FRICTION if tau_c == 0 else aj.LuGre(tau_c, 1.5 * tau_c)
    trial = aj.make_trial(
        aj.PD() if controller == "pd" else aj.IMBIC(),
        arm=paper.arm(LOCATION),
        friction=friction,
        sensors=aj.Sensors(force_noise=FORCE_NOISE),
        acquisition=acquisition,
    )
    start = time.perf_counter()
    sims = aj.simulate_batch(
        aj.batch.stack_trials([trial] * len(keys)), f_delta, keys=keys, numerics=aj.solvers.SWEEP_NUMERICS
    )
    sim_s = time.perf_counter() - start
    if np.any(sims.diverged):
        raise RuntimeError(f"{controller} at tau_c = {tau_c} N m: {int(np.sum(sims.diverged))} trials diverged")
    start = time.perf_counter()
    ests = jax.tree.map(np.asarray, _compiled("estimate")(f_delta, sims.x, sims.fh))
    arm = paper.arm(LOCATION)
    rows = []
    for label, kw in fits_of(acquisition):
        fits = jax.tree.map(np.asarray, _compiled(*sorted(kw.items()))(ests))
        inside = {}
        for sym, name in PARAMETERS:
            low, high = fits.interval(name)
            truth = np.asarray(getattr(arm, name))[None]
            inside[sym] = (low <= truth) & (truth <= high)  # (seeds, 2, 2)
        unknown, told = _warned(fits, len(keys), tau_c)
        quiet = ~told
        cover = {sym: v.mean(axis=0) for sym, v in inside.items()}
        rows.append(
            dict(
                controller=controller,
                tau_c=tau_c,
                acquisition=acquisition,
                fit=label,
                coverage={sym: c.tolist() for sym, c in cover.items()},
                coverage_min=float(min(c.min() for c in cover.values())),
                coverage_min_by={sym: float(c.min()) for sym, c in cover.items()},
                coverage_mean=float(np.mean([c.mean() for c in cover.values()])),
                warned=float(unknown.mean()),
                warned_told=float(told.mean()),
                unwarned=int(quiet.sum()),
                coverage_min_unwarned=(
                    float(min(v[quiet].mean(axis=0).min() for v in inside.values())) if quiet.any() else None
                ),
                lack_of_fit_median=float(np.median(fits.lack_of_fit_overall)),
                n_eff_median=float(np.median(ests.error.n_eff)),
            )
        )
    return rows, sim_s, time.perf_counter() - start


def table(rows) -> str:
    out = [
        "| controller | tau_c [N m] | simulated | fit | coverage min (M / B / K) | mean of 12 "
        "| warned: friction unknown | warned: told | min coverage unwarned (trials) | lack of fit (median) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        by = " / ".join(f"{r['coverage_min_by'][s]:.2f}" for s, _ in PARAMETERS)
        unw = "-" if r["coverage_min_unwarned"] is None else f"{r['coverage_min_unwarned']:.2f}"
        out.append(
            f"| {r['controller']} | {r['tau_c']:g} | {r['acquisition']} | {r['fit']} | {r['coverage_min']:.2f} ({by}) "
            f"| {r['coverage_mean']:.3f} | {r['warned']:.2f} | {r['warned_told']:.2f} | {unw} ({r['unwarned']}) "
            f"| {r['lack_of_fit_median']:.2f} |"
        )
    return "\n".join(out)


def run(args) -> None:
    """The benchmark of ``args`` (``bench_fit_coverage.py``'s): prints the table and writes
    ``fit_coverage.md`` and ``.json`` under ``args.out``."""
    import jax
    import numpy as np

    import armimp_jax as aj
    from armimp_jax import paper
    from armimp_jax.study.runs import results, seeds

    n = int(round(args.seconds * 1000))
    cases = CASES[:2] if args.quick else CASES
    peak = paper.perturbation_peak(1)
    f_delta = np.stack([seeds.seed_perturbation(20250, s, n, peak) for s in range(args.seeds)])
    keys = jax.random.split(jax.random.PRNGKey(20251), args.seeds)
    rows, timing = [], []
    for acquisition in args.acquisitions:
        for controller, tau_c in cases:
            case_rows, sim_s, fit_s = run_case(controller, tau_c, acquisition, f_delta, keys)
            rows += case_rows
            timing.append(
                dict(controller=controller, tau_c=tau_c, acquisition=acquisition, simulate_s=sim_s, fit_s=fit_s)
            )
            best = case_rows[0]
            print(
                f"{controller} tau_c={tau_c:g} {acquisition}: {args.seeds} x {args.seconds:g} s simulated in "
                f"{sim_s:.1f} s, fitted in {fit_s:.1f} s; {best['fit']}: coverage min {best['coverage_min']:.2f}, "
                f"warned {best['warned']:.2f}",
                flush=True,
            )
    text = table(rows)
    print(text)
    settings = dict(
        seeds=args.seeds,
        seconds=args.seconds,
        acquisitions=args.acquisitions,
        cases=[list(c) for c in cases],
        location=LOCATION,
        force_noise_n=FORCE_NOISE,
        perturbation_level=1,
        welch=dict(
            zip(("nperseg", "noverlap"), aj.spectra.welch_segments(n), strict=True), window="hann", fmax_hz=15.0
        ),
        version=aj.__version__,
        numerics="aj.SWEEP_NUMERICS",  # the records' label since 1.x (aj.solvers.SWEEP_NUMERICS)
        seed_keys=[20250, 20251],
    )
    args.out.mkdir(parents=True, exist_ok=True)
    header = (
        f"Fit coverage: {args.seeds} seeds x {args.seconds:g} s per case, paper arm {LOCATION}, "
        f"force noise {FORCE_NOISE} N\n\n"
    )
    results.atomic_write_text(args.out / "fit_coverage.md", header + text + "\n")
    results.atomic_write_json(args.out / "fit_coverage.json", dict(settings=settings, rows=rows, timing=timing))
    print(f"wrote {args.out / 'fit_coverage.md'} and {args.out / 'fit_coverage.json'}")
