"""Live progress of a campaign: done / aborted / failed, rate and ETA.

On a terminal (stderr is a TTY) a tqdm bar; otherwise plain lines at most every ``interval_s``
seconds and one at the end, so logs of batch jobs stay readable.
"""

from __future__ import annotations

import sys
import time
from typing import TextIO


def _clock(seconds: float) -> str:
    if seconds != seconds or seconds == float("inf"):
        return "?"
    s = int(round(seconds))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


def _rate(runs_per_s: float) -> str:
    """Runs per second to two significant digits below 10 (a real rig's 0.083 is not "0.1")."""
    return f"{runs_per_s:.1f}" if runs_per_s >= 10 else f"{runs_per_s:.2g}"


class Progress:
    """Counts of finished runs; ``total`` and the counts already terminal when the session began."""

    def __init__(
        self,
        label: str,
        total: int,
        done: int = 0,
        aborted: int = 0,
        failed: int = 0,
        *,
        stream: TextIO | None = None,
        interval_s: float = 5.0,
        bar: bool | None = None,
    ) -> None:
        self.label, self.total = label, total
        self.counts = {"done": done, "aborted": aborted, "failed": failed}
        self.initial = sum(self.counts.values())
        self.stream = stream or sys.stderr
        self.interval_s = interval_s
        self.started = time.monotonic()
        self._last_line = self.started
        use_bar = self.stream.isatty() if bar is None else bar
        self._bar = None
        if use_bar:
            from tqdm import tqdm

            class _Bar(tqdm):  # no monitor thread: the process pool forks after the bar exists
                monitor_interval = 0

            self._bar = _Bar(
                total=total, initial=self.initial, desc=label, unit="run", file=self.stream,
                dynamic_ncols=True, smoothing=0.1,
            )
            self._bar.set_postfix_str(self._counts())

    @property
    def finished(self) -> int:
        return sum(self.counts.values())

    def _counts(self) -> str:
        c = self.counts
        return f"done {c['done']} aborted {c['aborted']} failed {c['failed']}"

    def rate(self) -> float:
        """Runs per second in this session."""
        elapsed = time.monotonic() - self.started
        return (self.finished - self.initial) / elapsed if elapsed > 0 else 0.0

    def line(self) -> str:
        rate = self.rate()
        eta = (self.total - self.finished) / rate if rate > 0 else float("nan")
        return (
            f"{self.label}: {self.finished}/{self.total} ({self._counts()}) "
            f"{_rate(rate)} runs/s, elapsed {_clock(time.monotonic() - self.started)}, ETA {_clock(eta)}"
        )

    def update(self, state: str) -> None:
        """One more run in ``state`` (done | aborted | failed)."""
        self.counts[state] += 1
        if self._bar is not None:
            self._bar.update(1)
            self._bar.set_postfix_str(self._counts(), refresh=False)
        elif time.monotonic() - self._last_line >= self.interval_s:
            self.write(self.line())

    def tick(self) -> None:
        """Called while waiting: a plain line every ``interval_s`` even when no run finished."""
        if self._bar is not None:
            self._bar.refresh()
        elif time.monotonic() - self._last_line >= self.interval_s:
            self.write(self.line())

    def write(self, message: str) -> None:
        """A message that does not break the bar."""
        self._last_line = time.monotonic()
        if self._bar is not None:
            self._bar.write(message, file=self.stream)
        else:
            print(message, file=self.stream, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        print(self.line(), file=self.stream, flush=True)
