"""The benchmark of ``record_for`` (``sweeps/bench_record_for.py``): where a call's time goes,
its first call (compilation included) apart from its warm calls, on two realistic cases.

- ``paper``: IMBIC through LuGre 1.0 / 1.5 N m at the paper's arm location 2, the paper's
  level-1 perturbation (key 0), 20 s, the arm's three matrices free, the README's noise;
- ``design``: ``sweeps/configs/design_imbic.toml``'s trial at its arm location 2 (the same
  controller, friction and noise) under its starting multisine within its limits, 20 s.

For each case: ``record_for`` as it answers by default (the bound and one ``predict_se``), and
on demand with ``check=True`` (a second ``predict_se`` at the answer's length: what every call
ran before) and the parts alone: the bound (``crlb``), ``predict_se`` at the case's record and
at a longer one (the check of an answer that long; one warm call). Each timing
is ``block_until_ready``'d; the first call is reported apart, then the median of ``repeats``
calls, with the process's CPU seconds beside the wall seconds (on a shared host the wall
grows with the load, the CPU seconds much less).
"""

from __future__ import annotations

import json
import os
import pathlib
import statistics
import time

import jax
import numpy as np

import armimp_jax as aj
from armimp_jax import paper, runtime
from armimp_jax.study.design import design_experiment as dx

ARM = ("arm.mass", "arm.damping", "arm.stiffness")
NOISE = dict(sensors=aj.Sensors(force_noise=0.05, encoder_counts=2**18), voluntary=aj.VoluntaryForce(0.3, 2.0))
CONFIG = pathlib.Path(__file__).resolve().parents[2] / "sweeps" / "configs" / "design_imbic.toml"


def case(name: str):
    """``(trial, f (N, 2) [N])`` of the case ``name``."""
    if name == "paper":
        trial = aj.make_trial(aj.IMBIC(), arm=paper.arm(2), friction=aj.LuGre(1.0, 1.5), **NOISE)
        return trial, np.asarray(aj.perturbation(jax.random.key(0), 20_000, paper.perturbation_peak(1)))
    config = dx.read_design_config(CONFIG)
    trials, family, limits, options = dx.build_design(config, where=str(CONFIG))
    f = aj.signals.limited_signal(family, limits, key=jax.random.split(options["key"])[0], trials=trials)
    return trials[1], np.asarray(f)


def timed(call, repeats: int) -> dict:
    """The first call apart, then the median of ``repeats`` (wall and CPU seconds)."""

    def once():
        wall, cpu = time.perf_counter(), time.process_time()
        out = jax.block_until_ready(call())
        return out, time.perf_counter() - wall, time.process_time() - cpu

    out, first, first_cpu = once()
    runs = [once()[1:] for _ in range(repeats)]
    return dict(
        answer=out,
        first_s=first,
        first_cpu_s=first_cpu,
        warm_s=statistics.median(r[0] for r in runs),
        warm_cpu_s=statistics.median(r[1] for r in runs),
        runs_s=[r[0] for r in runs],
        load=os.getloadavg()[0],
    )


def measure(name: str, args) -> dict:
    """One case: ``record_for`` as it answers by default; with ``args.check`` also with its check;
    with ``args.parts`` the bound and ``predict_se`` alone, and ``predict_se`` at a record of
    ``args.check_record`` seconds (the check of an answer that long, what every call ran before)."""
    trial, f = case(name)
    key, draws, repeats = jax.random.key(0), args.draws, args.repeats
    out = {}
    answer = timed(lambda: aj.record_for(trial, f, free=ARM, draws=draws, key=key), repeats)
    out["record_for"] = answer
    print(f"{name}: record_for {summary(answer)}\n{answer['answer'].summary()}", flush=True)
    if args.check:
        checked = timed(lambda: aj.record_for(trial, f, free=ARM, draws=draws, key=key, check=True), repeats)
        out["record_for_check"] = checked
        print(f"{name}: record_for(check=True) {summary(checked)}\n{checked['answer'].summary()}", flush=True)
    if not args.parts:
        return out
    statistic = answer["answer"].statistic
    longer = np.resize(f, (int(round(args.check_record / trial.period)), 2))
    calls = {
        "crlb": (lambda: aj.crlb(trial, f, free=ARM), repeats),
        "predict_se": (
            lambda: aj.predict_se(trial, f, free=ARM, statistic=statistic, draws=draws, key=key).se,
            repeats,
        ),
        f"predict_se_at_{args.check_record:g}s": (
            lambda: aj.predict_se(trial, longer, free=ARM, statistic=statistic, draws=draws, key=key).se,
            1,
        ),
    }
    for part, (call, times) in calls.items():
        out[part] = timed(call, times)
        print(f"{name}: {part} {summary(out[part])}", flush=True)
    return out


def summary(t: dict) -> str:
    return (
        f"first {t['first_s']:.1f} s ({t['first_cpu_s']:.1f} CPU s), warm median {t['warm_s']:.1f} s "
        f"({t['warm_cpu_s']:.1f} CPU s) of {len(t['runs_s'])}; load {t['load']:.1f}"
    )


def _plain(t: dict) -> dict:
    """The timing without its answer, as JSON."""
    answer = t["answer"]
    row = {k: v for k, v in t.items() if k != "answer"}
    if isinstance(answer, aj.results.RecordLength):
        row.update(
            bound_min=answer.longest("bound") / 60,
            predicted_min=answer.longest("predicted") / 60,
            statistic=answer.statistic,
            check=answer.check,
        )
    return row


def main(args) -> int:
    runtime.configure()
    doc = dict(devices=jax.device_count(), cpus=os.cpu_count(), draws=args.draws, repeats=args.repeats)
    for name in args.cases:
        doc[name] = {k: _plain(v) for k, v in measure(name, args).items()}
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(doc, indent=1, default=float))
    return 0
