"""What a study says on the terminal while the engine runs it: one line saying what runs
where, a progress bar fed by the engine's progress reports, and the finishing steps, one
line each with its time. Pure Python: it imports no JAX.
"""

from __future__ import annotations

import itertools
import statistics
import sys
import time
from collections.abc import Callable


def clock(seconds: float) -> str:
    """``m:ss`` of ``seconds``."""
    return f"{int(seconds // 60)}:{int(seconds % 60):02d}"


class ProgressBar:
    """The run's progress on one line of ``stream``, then its finishing steps, one line each.

    ``batches`` are ``(trials, trial samples)`` per batch, in run order. The ETA leaves
    compilation out: it counts the rate over the chunks that did not start a batch (a batch's
    first chunk also compiles it, after the previous batch's estimation), plus the measured
    cost of each batch start for the batches still to come; until a steady rate is known it
    says "compiling". The bar ends at 100% with every trial.
    """

    def __init__(self, batches: list[tuple[int, int]], stream=None):
        self.stream = stream or sys.stderr
        self.trials_total = sum(n for n, _ in batches)
        self.first = batches[0][0] if batches else 0
        self.ends = list(itertools.accumulate(s for _, s in batches))
        self.total = self.ends[-1] if self.ends else 0
        self.start = time.monotonic()
        self.last_draw = -1.0
        self.prev = None  # (time, done, trials_done) of the previous call
        self.steady_s = self.steady_work = 0.0  # time and trial samples of chunks that did not start a batch
        self.starts: list[float] = []  # measured extra cost of starting a batch (estimation, compilation)

    def begin(self) -> None:
        first = f" ({self.first} trials)" if self.ends else ""
        self._draw(0, 0, f"compiling the first batch{first}...", force=True)

    def _rate(self):
        return self.steady_work / self.steady_s if self.steady_s > 0 and self.steady_work > 0 else None

    def __call__(self, p: dict) -> None:
        now = time.monotonic()
        done, trials = p["done"], p["trials_done"]
        rate = self._rate()
        if self.prev is not None:
            t_prev, done_prev, trials_prev = self.prev
            if trials == trials_prev:
                self.steady_s += now - t_prev
                self.steady_work += done - done_prev
            elif rate is not None:  # a batch started: what it cost beyond its simulation
                self.starts.append(max(0.0, now - t_prev - (done - done_prev) / rate))
        self.prev = (now, done, trials)
        rate = self._rate()
        batch = sum(1 for e in self.ends if e <= done)  # batches whose simulation is over
        if done >= self.total:
            status = "simulated; estimating the last batch..."
        elif done in self.ends:
            status = f"estimating batch {batch}/{len(self.ends)}, then compiling the next..."
        elif rate is None:  # the first chunk (and compilation) is over; the rate needs one more
            status = "ETA after the next chunk"
        else:
            per_start = statistics.fmean(self.starts) if self.starts else 0.0
            eta = (self.total - done) / rate + per_start * max(0, len(self.ends) - batch - 1)
            status = f"ETA {clock(eta)}"
        self._draw(done, trials, status, force=done in self.ends or done >= self.total)

    def _draw(self, done, trials, status, *, force=False) -> None:
        now = time.monotonic()
        if not force and now - self.last_draw < 0.5:
            return
        self.last_draw = now
        frac = min(1.0, done / self.total) if self.total else 1.0
        bar = "#" * int(30 * frac) + "." * (30 - int(30 * frac))
        self.stream.write(
            f"\r[{bar}] {100 * frac:5.1f}% simulated  trials saved {trials}/{self.trials_total}  "
            f"elapsed {clock(now - self.start)}  {status:<50s}"
        )
        self.stream.flush()

    def end(self, trials_done: int) -> None:
        """The last line of the bar: the trials simulated, estimated and saved (every one of
        them, unless the run stopped early)."""
        done = self.total if trials_done >= self.trials_total else self.prev[1] if self.prev else 0
        self._draw(done, trials_done, "done", force=True)
        self.stream.write("\n")
        self.stream.flush()


class Console:
    """A study's voice on the terminal: ``starter(header)`` is the engine's ``on_start`` (it
    prints ``header(on disk, to run)`` on ``out`` and begins the bar), ``progress`` the
    engine's progress callback, ``end`` closes the bar, ``step`` runs a finishing step. With
    ``quiet`` it says nothing."""

    def __init__(self, *, stream=None, out=None, quiet: bool = False):
        self._stream, self._out, self.quiet = stream, out, quiet
        self.bar: ProgressBar | None = None

    @property
    def stream(self):  # sys.stderr when asked, not when made (a test may have replaced it since)
        return self._stream or sys.stderr

    @property
    def out(self):
        return self._out or sys.stdout

    def starter(self, header: Callable[[int, int], str]) -> Callable[[int, list], None]:
        def on_start(on_disk: int, batches: list[tuple[int, int]]) -> None:
            if self.quiet:
                return
            print(header(on_disk, sum(n for n, _ in batches)), file=self.out, flush=True)
            if batches:
                self.bar = ProgressBar(batches, self.stream)
                self.bar.begin()

        return on_start

    def progress(self, p: dict) -> None:
        if self.bar is not None:
            self.bar(p)

    def end(self, trials_done: int) -> None:
        if self.bar is not None:
            self.bar.end(trials_done)
            self.bar = None

    def step(self, name: str, fn: Callable):
        """Run ``fn()``, one finishing step, saying what it is and how long it took."""
        if self.quiet:
            return fn()
        self.stream.write(f"{name}...")
        self.stream.flush()
        t0 = time.perf_counter()
        result = fn()
        self.stream.write(f" {time.perf_counter() - t0:.1f} s\n")
        self.stream.flush()
        return result

    def warn(self, prog: str) -> Callable[[str], None]:
        """The ``warn`` of a script named ``prog``: one line ``PROG: warning: ...`` on the stream."""

        def warn(message: str) -> None:
            self.stream.write(f"{prog}: warning: {message}\n")

        return warn
