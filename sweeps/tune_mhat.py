"""Tune IMBIC's gain Mhat by gradient descent on phi_T through the whole simulator.

    python sweeps/tune_mhat.py                     # 30 Adam steps on 16 s records, held-out eval at paper settings
    python sweeps/tune_mhat.py --quick             # a smoke run (tiny records, 3 steps)
    python sweeps/tune_mhat.py --resume DIR        # continue from the last saved iteration

Writes DIR/mhat.json (the tuned gain), DIR/loss_curve.png, DIR/comparison.md (phi_T of
the tuned Mhat vs hand-picked ones on held-out seeds, every location and friction level)
and the resumable optimiser state (DIR/tune_state.json/.npz). Default DIR: results/tune.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import sys
import time

from armimp_jax.runtime import configure


def parse(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--iterations", type=int, default=30)
    ap.add_argument("--lr", type=float, default=0.1, help="Adam learning rate (in log-Mhat units)")
    ap.add_argument("--parameterisation", choices=["diagonal", "full"], default="diagonal")
    ap.add_argument(
        "--mode",
        choices=["forward", "reverse"],
        default="reverse",
        help="gradient mode (reverse: 2x faster than forward in bench_gradient.py)",
    )
    ap.add_argument("--start", type=float, default=0.25, help="starting Mhat, times the identity [kg]")
    ap.add_argument("--phi-ij-weight", type=float, default=0.0)
    ap.add_argument("--train-seconds", type=float, default=16.0)
    ap.add_argument("--train-substeps", type=int, default=20)
    ap.add_argument("--train-nperseg", type=int, default=4096)
    ap.add_argument("--train-seeds", type=int, default=2)
    ap.add_argument("--frictions", type=int, nargs="+", default=[1, 2], help="training friction levels")
    ap.add_argument("--eval-every", type=int, default=10, help="held-out evaluation every N steps (0: off)")
    ap.add_argument("--eval-seeds", type=int, default=2)
    ap.add_argument(
        "--compare",
        type=float,
        nargs="+",
        default=[0.25, 0.5, 1.0, 1.5],
        help="hand-picked Mhat values (times I) for the final table",
    )
    ap.add_argument("--out", type=pathlib.Path, default=None)
    ap.add_argument("--resume", type=pathlib.Path, metavar="DIR")
    return ap.parse_args(argv)


def main(argv=None):
    args = parse(argv)
    configure()
    import numpy as np

    from armimp_jax import Welch, tune
    from armimp_jax.paper import tune as paper_tune

    if args.quick:
        # 20 substeps: fewer put RK4 near its stability limit on the stiff LuGre bristles
        train = dict(seconds=2.5, substeps=20, welch=Welch(512, 384))
        evals = dict(seconds=2.5, substeps=20, welch=Welch(512, 384))
        args.iterations, args.eval_every = min(args.iterations, 3), 0
        locations = (1, 2)
    else:
        train = dict(
            seconds=args.train_seconds,
            substeps=args.train_substeps,
            welch=Welch(args.train_nperseg, 3 * args.train_nperseg // 4),
        )
        evals = dict(seconds=50.0, substeps=100, welch=Welch())
        locations = (1, 2, 3, 4)
    out = args.resume or args.out or pathlib.Path("results/tune-quick" if args.quick else "results/tune")
    out.mkdir(parents=True, exist_ok=True)
    config = tune.TuneConfig(
        parameterisation=args.parameterisation,
        learning_rate=args.lr,
        iterations=args.iterations,
        mode=args.mode,
        phi_ij_weight=args.phi_ij_weight,
        numerics=paper_tune.training_numerics(train["substeps"]),
    )
    train["welch"].check(int(train["seconds"] * 1000))
    params, f_delta = paper_tune.training_batch(
        tuple(args.frictions), locations, tuple(range(args.train_seeds)), seconds=train["seconds"]
    )
    state_path = out / "tune_state"
    state = tune.load_state(state_path, config) if args.resume else None
    eval_seeds = tuple(range(args.eval_seeds))

    def evaluate(iteration, theta):
        mhat = np.asarray(tune.mhat_from_theta(theta, config.parameterisation))
        phi = paper_tune.heldout_phi(
            {"current": mhat},
            locations=locations,
            seeds=eval_seeds,
            seconds=evals["seconds"],
            substeps=evals["substeps"],
            welch=evals["welch"],
        )
        return dict(mean_phi_T=float(phi["current"].mean()), diverged=bool(phi["_diverged"]))

    def log(rec):
        keep = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in rec.items() if k != "phi_T"}
        print(json.dumps(keep), flush=True)

    print(
        f"training on {params.q0.shape[0]} trials of {train['seconds']:g} s ({train['substeps']} substeps), "
        f"{config.mode}-mode gradients -> {out}",
        flush=True,
    )
    start = time.perf_counter()
    theta0 = tune.theta_from_mhat(args.start * np.eye(2), config.parameterisation)
    try:
        state = tune.tune(
            theta0,
            params,
            f_delta,
            train["welch"],
            config,
            state=state,
            log=log,
            on_iteration=lambda st: tune.save_state(state_path, st, config),
            evaluate=evaluate,
            eval_every=args.eval_every,
        )
    except KeyboardInterrupt:
        print(f"interrupted; resume with: python sweeps/tune_mhat.py --resume {out}")
        return 130
    tune.save_state(state_path, state, config)
    mhat = np.asarray(tune.mhat_from_theta(state["theta"], config.parameterisation))
    (out / "mhat.json").write_text(
        json.dumps(
            dict(
                mhat=mhat.tolist(),
                config=dataclasses.asdict(config),
                train_loss=state["value"],
                train_s=time.perf_counter() - start,
            ),
            indent=1,
        )
    )
    from armimp_jax.paper.plots import loss_curve

    loss_curve(state["history"], out / "loss_curve.png")
    candidates = {"tuned": mhat} | {f"{v:g} I": v * np.eye(2) for v in args.compare}
    table = paper_tune.heldout_phi(
        candidates,
        locations=locations,
        seeds=eval_seeds,
        seconds=evals["seconds"],
        substeps=evals["substeps"],
        welch=evals["welch"],
    )
    md = paper_tune.comparison_markdown(table, mhat, locations=locations, evals=evals, seeds=eval_seeds)
    (out / "comparison.md").write_text(md)
    (out / "comparison.json").write_text(
        json.dumps({k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in table.items()}, indent=1)
    )
    print(md)
    print(f"tuned Mhat = {np.round(mhat, 4).tolist()} kg; done in {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except ValueError as err:
        sys.exit(f"error: {err}")
