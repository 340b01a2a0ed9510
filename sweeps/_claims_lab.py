"""The trials of ``explain_claims.py``: what one trial is, how a batch of them runs and is
measured, and the seed statistics its tables print.

Runs go through the study engine's batches (``armimp_jax.study.engine.map_batches``), one
compiled batch per static setting; seed ``s`` draws its perturbation from
``fold_in(PRNGKey(0), s)`` (``armimp_jax.study.seeds``), like ``reproduce_paper.py``.
JAX is imported at first use, so that ``--help`` stays quick.
"""

from __future__ import annotations

import dataclasses

SLIDE_RATE = 0.01  # [rad/s]; pre-sliding bristle motion stays below ~2e-3 rad/s at 15 Hz
PAPER_PEAKS = {1: 2.25, 2: 3.75, 3: 4.5}  # [N], the paper's Table 3
SIGMA1_LOW = 10.0  # [N m s/rad]: Table 1 lost sigma1's typesetting; ours is sqrt(1e5) ~ 316
BASE_SEED = 0  # the reproduction's


@dataclasses.dataclass(frozen=True)
class Setup:
    """How one study runs: record lengths [s] and the Welch segments [samples] to compare."""

    short: float = 50.0
    long: float = 200.0
    nperseg: int = 8192
    fine: int = 32768
    seeds: int = 3
    seeds_b: int = 10


FULL = Setup()
QUICK = Setup(short=6.0, long=12.0, nperseg=1024, fine=4096, seeds=2, seeds_b=2)


@dataclasses.dataclass(frozen=True)
class Run:
    """One trial: controller, arm location, friction (paper level, or Coulomb torque with
    stiction 1.5x), perturbation peak [N], seed, IMBIC's Mhat [kg] and acceleration
    estimate, acquisition, record length [s]."""

    controller: str
    location: int
    seed: int
    seconds: float
    level: int | None = None
    tau_c: float | None = None
    peak: float = PAPER_PEAKS[1]
    mhat: float = 0.25
    accel: str = "velocity"
    acquisition: str = "instant"
    sigma1: float | None = None  # bristle damping [N m s/rad]; None: the paper's (Canudas de Wit's)

    @property
    def static(self):
        return (self.controller, self.accel if self.controller == "imbic" else "", self.acquisition, self.seconds)

    def trial(self):
        """The run's ``Trial`` on MIT-MANUS."""
        import numpy as np

        import armimp_jax as aj
        from armimp_jax import paper

        if self.controller == "pd":
            ctrl = aj.PD()
        else:
            ctrl = aj.IMBIC(self.mhat * np.eye(2), accel_estimate=self.accel)
        return aj.make_trial(ctrl, arm=paper.arm(self.location), friction=self.friction(), acquisition=self.acquisition)

    def friction(self):
        import armimp_jax as aj
        from armimp_jax import paper

        if self.level is not None:
            lugre = paper.friction(self.level)
        else:
            lugre = aj.LuGre(tau_c=self.tau_c, tau_s=1.5 * self.tau_c)
        return lugre if self.sigma1 is None else dataclasses.replace(lugre, sigma1=self.sigma1)


class Lab:
    """Runs ``Run`` values in batches (one per static setting) and measures each record."""

    def __init__(self, batch_size: int):
        import jax

        jax.config.update("jax_enable_x64", True)
        self.batch_size = batch_size
        self._signals: dict = {}
        self.trials = 0

    def signal(self, seed: int, seconds: float, peak: float):
        from armimp_jax.study.seeds import seed_perturbation

        key = (seed, seconds, peak)
        if key not in self._signals:
            self._signals[key] = seed_perturbation(BASE_SEED, seed, int(round(seconds * 1000)), peak)
        return self._signals[key]

    def run(self, runs: list[Run], welch: dict) -> list[dict]:
        """Metrics of every run, in order: ``welch`` maps a record length [s] to the Welch
        segments [samples] to estimate with (overlap 3/4), each giving its own metrics under
        ``"w<nperseg>"``; plus the run's sliding share and stiction-torque share."""
        import numpy as np

        import armimp_jax as aj
        from armimp_jax.study.engine import map_batches

        def batch(rs: list[Run]) -> list[dict]:
            f_delta = np.stack([self.signal(r.seed, r.seconds, r.peak) for r in rs])
            sim = aj.simulate_batch(aj.stack_trials([r.trial() for r in rs]), f_delta, numerics=aj.SWEEP_NUMERICS)
            self.trials += len(rs)
            return [measure(r, f_delta[j], sim, j, welch[r.seconds]) for j, r in enumerate(rs)]

        return map_batches(runs, lambda r: r.static, self.batch_size, batch)


def measure(r: Run, f_delta, sim, j: int, segments) -> dict:
    """Trial ``j`` of a batch's simulation: whether it diverged, its sliding share, its
    perturbation-torque share over stiction, its bristle load, and per Welch segment the
    study's ``trial_metrics`` with the coherence minimum and where it falls."""
    import numpy as np

    import armimp_jax as aj

    q = np.asarray(sim.q[j])
    m = dict(diverged=bool(sim.diverged[j]))
    m["slide"] = float(np.mean(np.any(np.abs(np.diff(q, axis=0)) * 1000.0 > SLIDE_RATE, axis=1)))
    # the perturbation's own joint torque J(q0)^T F_Delta against the stiction torque
    tau = np.abs(f_delta @ np.asarray(aj.jacobian(q[0], aj.MIT_MANUS)))  # (N, 2): J^T F per sample
    lugre = r.friction()
    tau_s = float(np.max(lugre.tau_s))
    m["over_stiction"] = float(np.mean(np.any(tau > tau_s, axis=1))) if tau_s > 0 else float("nan")
    # bristle load sigma0 |z| / tau_s: ~0 a linear spring, -> 1 at breakaway (LuGre's z' = v - sigma0 |v| z / g)
    load = np.max(np.abs(np.asarray(sim.z[j])) * np.asarray(lugre.sigma0), axis=1) / tau_s if tau_s > 0 else None
    m["load_p95"] = float(np.percentile(load, 95)) if load is not None else float("nan")
    for seg in segments:
        m[f"w{seg}"] = estimate_metrics(r, f_delta, sim, j, seg)
    return m


def estimate_metrics(r: Run, f_delta, sim, j: int, seg: int) -> dict:
    """``trial_metrics`` of trial ``j``'s estimate with ``seg``-sample segments (overlap 3/4),
    plus the lowest multiple coherence of x, its bin, and its bin below 2 Hz."""
    import numpy as np

    import armimp_jax as aj
    from armimp_jax import paper
    from armimp_jax.study.metrics import trial_metrics

    est = aj.estimate(f_delta, sim.x[j], sim.fh[j], nperseg=seg, noverlap=3 * seg // 4, errors=False)
    arrays = {k: np.asarray(v) for k, v in est._asdict().items()}
    f = arrays["f"]
    mm = trial_metrics(f, arrays["Z"], arrays, paper.arm(r.location))
    coh = arrays["coh_multiple_x"]
    k = np.unravel_index(np.argmin(coh), coh.shape)
    low = f < 2.0
    mm["coh_min"] = float(coh.min())
    mm["coh_min_f"] = float(f[k[0]])
    mm["coh_min_low_f"] = float(f[low][np.argmin(coh[low].min(axis=1))]) if low.any() else float("nan")
    return mm


# --- statistics and tables -----------------------------------------------------------------


def ci(values) -> tuple[float, float | None]:
    """Mean and half-width of the 95% t-interval over seeds (``None`` under two values)."""
    import numpy as np

    from armimp_jax.study.stats import mean_ci

    v = np.asarray([x for x in values if np.isfinite(x)], dtype=float)
    if v.size == 0:
        return float("nan"), None
    mean, _, half = mean_ci(v)
    return float(mean), None if half is None else float(half)


def pm(values, fmt=".3g") -> str:
    mean, half = ci(values)
    if mean != mean:
        return "—"
    return format(mean, fmt) if half is None else f"{format(mean, fmt)} ± {format(half, fmt)}"


def span(values, fmt=".2f") -> str:
    return f"{format(min(values), fmt)}-{format(max(values), fmt)}"


def table(head: list[str], rows: list[list]) -> list[str]:
    return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)] + [
        "| " + " | ".join(str(c) for c in row) + " |" for row in rows
    ]
