"""Live progress of a campaign or an analysis, and the words every command counts runs with.

A point's **outcome** is one of :data:`OUTCOMES`: a run ``completed``, found ``no-motion`` (its
input too small to move the load), was ``aborted`` by the safety routine, or ``failed`` (an error,
not the plant); a point without a finished run is ``claimed`` (running) or ``planned``.
``labrunner run``, ``resume``, ``status``, ``analyse`` and the report count with
:func:`format_counts`, so they say the same thing in the same words.

On a terminal (stderr is a TTY) a tqdm bar; otherwise plain lines: one at once (so a log shows
the command started), then at most every ``interval_s`` seconds, and one at the end, so logs of
batch jobs stay readable.

A campaign's counts are whole runs with a finished outcome; the runs in flight are shown apart,
with the share of their ticks done (``12/320 (… ; 32 running, 31 % through, 32 waiting)``, from
:mod:`labrunner.campaign.live`). The bar's position, the rate and the ETA count those
run-equivalents too, so they are right before the first lockstep batch ends. The runner also
writes them into its lock record every second (:meth:`labrunner.campaign.lock.DirectoryLock.publish`),
so that ``status`` from another terminal gives the rate and ETA the runner shows.
"""

from __future__ import annotations

import abc
import math
import sys
import time
from collections.abc import Callable, Mapping
from typing import TextIO

#: A point's outcome, in the order counts are given everywhere.
OUTCOMES = ("completed", "no-motion", "aborted", "failed", "claimed", "planned")
#: Outcomes of a finished run.
FINISHED = OUTCOMES[:4]
PUBLISH_S = 1.0  # at most this often the rate and ETA go to ``publish`` (the runner's lock record) [s]


def format_counts(counts: Mapping[str, int]) -> str:
    """``"51 completed, 2 no-motion, 0 aborted, 0 failed"`` (then claimed and planned if any)."""
    shown = [w for w in OUTCOMES if w in FINISHED or counts.get(w, 0)]
    return ", ".join(f"{int(counts.get(w, 0))} {w}" for w in shown)


def _clock(seconds: float) -> str:
    if seconds != seconds or seconds == float("inf"):
        return "?"
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


def _rate(per_s: float) -> str:
    """Items per second to two significant digits below 10 (a real rig's 0.083 is not "0.1")."""
    return f"{per_s:.1f}" if per_s >= 10 else f"{per_s:.2g}"


class _Reporter(abc.ABC):
    """A tqdm bar on a terminal, else periodic plain lines; subclasses say what a line holds."""

    unit = "run"

    def __init__(
        self, label: str, total: int, initial: int, *, stream: TextIO | None, interval_s: float, bar: bool | None
    ) -> None:
        self.label, self.total, self.initial = label, total, initial
        self.stream = stream or sys.stderr
        self.interval_s = interval_s
        self.publish: Callable[[dict], None] | None = None  # where the rate and ETA also go (Progress)
        self._published = float("-inf")
        self.started = time.monotonic()
        self._last_line, self._last_text = self.started, ""
        self._bar = None
        if self.stream.isatty() if bar is None else bar:
            from tqdm import tqdm

            reporter = self

            class _Bar(tqdm):  # no monitor thread: analyse forks its drawing children after the bar exists
                monitor_interval = 0

                @property
                def format_dict(self):  # the whole items done, while the bar's n may hold a fraction
                    return {**super().format_dict, "finished": reporter.finished}

            self._bar = _Bar(
                total=total,
                initial=initial,
                desc=label,
                unit=self.unit,
                file=self.stream,
                dynamic_ncols=True,
                smoothing=0.1,
                bar_format="{l_bar}{bar}| {finished}/{total_fmt} [{elapsed}<{remaining}, {rate_fmt}{postfix}]",
            )
            self._bar.set_postfix_str(self.detail())
        else:
            self.write(self.line())  # from the first second, not after the first result

    @property
    @abc.abstractmethod
    def finished(self) -> int:
        """Items done so far (runs of a campaign, steps of an analysis)."""

    @property
    def position(self) -> float:
        """Items done, with the share done of those under way (what rate and ETA count)."""
        return float(self.finished)

    def detail(self) -> str:
        return ""

    def rate(self) -> float:
        """Items per second in this session."""
        elapsed = time.monotonic() - self.started
        return (self.position - self.initial) / elapsed if elapsed > 0 else 0.0

    def line(self) -> str:
        rate, eta = self.estimate()
        detail = f" ({self.detail()})" if self.detail() else ""
        return (
            f"{self.label}: {self.finished}/{self.total}{detail} {_rate(rate)} {self.unit}s/s, "
            f"elapsed {_clock(time.monotonic() - self.started)}, ETA {_clock(eta)}"
        )

    def estimate(self) -> tuple[float, float]:
        """(items per second, seconds left: NaN while unknown) as :meth:`line` shows them."""
        rate = self.rate()
        left = self.total - self.position
        return rate, 0.0 if left <= 0 else left / rate if rate > 0 else float("nan")  # nothing left: no "?"

    def _moved(self) -> None:
        if self._bar is not None:  # the words first: update() draws them with the position
            self._bar.set_postfix_str(self.detail(), refresh=False)
            self._bar.update(self.position - self._bar.n)
        elif time.monotonic() - self._last_line >= self.interval_s:
            self.write(self.line())
        self._publish()

    def _publish(self) -> None:
        """Hand the rate and ETA to ``publish`` (at most every :data:`PUBLISH_S`), for ``status``."""
        now = time.monotonic()
        if self.publish is None or now - self._published < PUBLISH_S:
            return
        self._published = now
        rate, eta = self.estimate()
        self.publish(
            {
                "at": time.time(),
                "position": round(self.position, 3),
                "total": self.total,
                "rate_per_s": round(rate, 4),
                "estimate_s": None if math.isnan(eta) else round(eta, 1),
            }
        )

    def tick(self) -> None:
        """Called while waiting: a plain line every ``interval_s`` even when nothing finished."""
        self._moved()
        if self._bar is not None:
            self._bar.refresh()

    def write(self, message: str) -> None:
        """A message that does not break the bar."""
        self._last_line, self._last_text = time.monotonic(), message
        if self._bar is not None:
            self._bar.write(message, file=self.stream)
        else:
            print(message, file=self.stream, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        line = self.line()
        if line != self._last_text:  # a session with nothing to do printed it already
            print(line, file=self.stream, flush=True)


class Progress(_Reporter):
    """Runs of a campaign by outcome; ``counts`` are those the ledger held when the session began
    (outcome words of :data:`OUTCOMES`; claimed and planned ones are what is left to run)."""

    def __init__(
        self,
        label: str,
        total: int,
        counts: Mapping[str, int] | None = None,
        *,
        stream: TextIO | None = None,
        interval_s: float = 5.0,
        bar: bool | None = None,
        publish: Callable[[dict], None] | None = None,
    ) -> None:
        self.counts = {w: int((counts or {}).get(w, 0)) for w in FINISHED}
        self.running = 0  # runs handed to the executor and not yet counted
        self.taken: int | None = None  # of those, the runs a worker has taken (None: not known)
        self.in_flight = 0.0  # run-equivalents the started runs have done (their batches' share of ticks)
        super().__init__(label, total, sum(self.counts.values()), stream=stream, interval_s=interval_s, bar=bar)
        self.publish = publish  # the runner's lock record: `status` from another terminal shows this rate and ETA

    @property
    def finished(self) -> int:
        return sum(self.counts.values())

    @property
    def position(self) -> float:
        return self.finished + min(self.in_flight, self.running)

    def detail(self) -> str:
        """The counts; then, apart, the runs in flight: ``; 16 running, 31 % through, 16 waiting``
        (waiting: submitted, no worker free yet; without a live channel only ``; 16 running``)."""
        flight = ""
        if self.running and self.taken is not None:
            started = min(self.taken, self.running)
            share = f", {100 * min(self.in_flight / started, 1.0):.0f} % through" if started else ""
            waiting = f", {self.running - started} waiting" if self.running > started else ""
            flight = f"; {started} running{share}{waiting}"
        elif self.running:
            flight = f"; {self.running} running"
        return format_counts(self.counts) + flight

    def started_runs(self, n: int) -> None:
        """``n`` more runs handed to the executor (shown until they are counted)."""
        self.running += n

    def live(self, in_flight: float, started: int | None) -> None:
        """What the live channel says (:meth:`Scheduler.live`): run-equivalents done by the
        started runs, and how many runs have started (a returned batch's runs count as started
        and whole until :meth:`update` counts each)."""
        self.in_flight, self.taken = in_flight, started

    def returned(self, n: int) -> None:
        """``n`` runs handed out will not be counted in this session (unclaimed, or left claimed for resume)."""
        self.running = max(0, self.running - n)

    def update(self, outcome: str) -> None:
        """One more run with ``outcome`` (completed | no-motion | aborted | failed)."""
        self.counts[outcome] += 1
        self.running = max(0, self.running - 1)
        self.in_flight = max(0.0, self.in_flight - 1.0)  # it was in flight, whole
        if self.taken is not None:
            self.taken = max(0, self.taken - 1)
        self._moved()


class Steps(_Reporter):
    """Progress of a long analysis: items done out of ``total`` (logs read, figures drawn), with
    the step under way named in each line."""

    unit = "step"

    def __init__(
        self, label: str, total: int, *, stream: TextIO | None = None, interval_s: float = 2.0, bar: bool | None = None
    ) -> None:
        self.done, self.step = 0, "starting"
        super().__init__(label, total, 0, stream=stream, interval_s=interval_s, bar=bar)

    @property
    def finished(self) -> int:
        return self.done

    def detail(self) -> str:
        return self.step

    def begin(self, step: str, more: int = 0) -> None:
        """Start ``step``; ``more`` items join the total (e.g. the logs it will read)."""
        self.step, self.total = step, self.total + more
        if self._bar is not None:
            self._bar.total = self.total
            self._bar.set_postfix_str(step)
        elif time.monotonic() - self._last_line >= self.interval_s:
            self.write(self.line())

    def advance(self, n: int = 1) -> None:
        self.done += n
        if self.done > self.total:  # more items than announced (e.g. logs read while building a table)
            self.total = self.done
            if self._bar is not None:
                self._bar.total = self.total
        self._moved()
