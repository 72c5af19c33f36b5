"""The live view: ``labrunner run --live`` serves the running campaign to the Foxglove app (docs/live.md).

The runner (the parent process) publishes through the Foxglove SDK's WebSocket server
(``foxglove-sdk``; subprotocol ``foxglove.sdk.v1``), JSON-encoded channels with JSON schemas:

- ``/campaign/progress``: the counts by outcome, runs in flight and the share of their ticks
  done, rate and ETA (what the progress line says), at most :data:`PROGRESS_HZ` times a second;
- ``/campaign/run``: each finished run (point id, grid parameters, outcome, metrics);
- ``/campaign/last_runs``: the last :data:`LAST_RUNS` finished runs as one table (Table panel);
- ``/run/signals``: the signals of one *representative run* per batch, its middle point
  (:func:`labrunner.campaign.live.representative`):
  ``t`` and one array per signal, the tracked output, its reference, the error and the first
  input also under the role names ``output``, ``reference``, ``error``, ``input`` (so that one
  layout serves every rig). A run of more than :data:`MAX_SAMPLES` samples is decimated (every
  n-th sample) and the message says so (``rate_hz``, ``decimation``).

A run's signals reach the runner two ways. While its batch runs in a pool worker, the
representative run's four role signals so far come through the live channel's shared memory
(:mod:`labrunner.campaign.live`); the scheduler hands the oldest running batch's to
:meth:`LiveView.progress` (``outcome: "running"``). Once its batch is committed, its whole log
is read and published (every signal, outcome, metrics) by a thread of the view that keeps only
the newest run waiting, so the scheduler's loop never reads a log (a Dask worker's or a real
rig's run is shown only so). A client that reads slowly loses its oldest messages (the SDK's
per-client backlog, :data:`BACKLOG`); it never holds up the runner.
"""

from __future__ import annotations

import contextlib
import ipaddress
import math
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from labrunner.campaign import live
from labrunner.campaign.progress import FINISHED, Progress
from labrunner.errors import CampaignError, InvalidParameter

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765  # the Foxglove app's default for a WebSocket connection
PROGRESS_HZ = 4.0  # /campaign/progress messages per second, at most
LAST_RUNS = 20  # rows of /campaign/last_runs
MAX_SAMPLES = live.SIGNAL_SAMPLES  # samples per signal in one /run/signals message; longer runs are decimated
BACKLOG = 256  # messages buffered per client before its oldest are dropped

_NUMBER = {"type": "number"}
_ARRAY = {"type": "array", "items": {"type": ["number", "null"]}}
_OBJECT = {"type": "object"}
_RUN_FIELDS = {
    "point_id": {"type": "string"},
    "outcome": {"type": "string"},
    "parameters": _OBJECT,
    "metrics": _OBJECT,
}
SCHEMAS: dict[str, dict[str, Any]] = {
    "/campaign/progress": {
        "type": "object",
        "title": "labrunner.CampaignProgress",
        "properties": {
            "campaign": {"type": "string"},
            "total": _NUMBER,
            "finished": _NUMBER,
            **{w.replace("-", "_"): _NUMBER for w in FINISHED},
            "running": _NUMBER,
            "through_percent": _NUMBER,
            "runs_per_s": _NUMBER,
            "elapsed_s": _NUMBER,
            "eta_s": {"type": ["number", "null"]},
            "session_ended": {"type": "boolean"},
        },
    },
    "/campaign/run": {"type": "object", "title": "labrunner.RunFinished", "properties": _RUN_FIELDS},
    "/campaign/last_runs": {
        "type": "object",
        "title": "labrunner.LastRuns",
        "properties": {"runs": {"type": "array", "items": {"type": "object", "properties": _RUN_FIELDS}}},
    },
    "/run/signals": {
        "type": "object",
        "title": "labrunner.RunSignals",
        "properties": {
            **_RUN_FIELDS,
            "fs": _NUMBER,
            "rate_hz": _NUMBER,
            "decimation": _NUMBER,
            "names": _OBJECT,
            "units": _OBJECT,
            "t": _ARRAY,
            "output": _ARRAY,
            "reference": _ARRAY,
            "error": _ARRAY,
            "input": _ARRAY,
            "signals": {"type": "object", "additionalProperties": _ARRAY},
        },
    },
}


@dataclass(frozen=True)
class Address:
    """Where the view listens; ``expose``: a non-loopback host was allowed (``--live-expose``)."""

    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT
    expose: bool = False


def parse_address(text: str, *, expose: bool = False) -> Address:
    """``--live`` [PORT | HOST:PORT] (empty: 127.0.0.1:8765; port 0: any free port). A host that
    is not a loopback address needs ``expose``: the view has no authentication."""
    field, allowed = "--live", "a port 0-65535 or HOST:PORT (0: any free port)"
    host, sep, port_text = text.strip().rpartition(":")
    if not sep:
        host = DEFAULT_HOST
    host = host.strip("[]") or DEFAULT_HOST  # [::1]:8765
    if not port_text and not sep:
        port = DEFAULT_PORT
    elif port_text.isdigit() and int(port_text) <= 65535:
        port = int(port_text)
    else:
        raise InvalidParameter(field, f"must be {allowed}, got {text!r}")
    if not _loopback(host) and not expose:
        raise InvalidParameter(
            field,
            f"{host} is not a loopback address: the live view would serve the campaign, unauthenticated, to every "
            f"host that reaches it; add --live-expose to allow that, or use 127.0.0.1",
        )
    return Address(host, port, expose and not _loopback(host))


def _loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _number(value: Any) -> Any:
    """A metric as JSON: NaN and ±inf as null."""
    return value if not isinstance(value, float) or math.isfinite(value) else None


def _finite(values: np.ndarray) -> list[float | None]:
    """JSON numbers of an array; NaN and ±inf as null (JSON has neither)."""
    out = values.tolist()
    if not np.isfinite(values).all():
        out = [v if math.isfinite(v) else None for v in out]
    return out


def signals_message(path: Path, point_id: str, parameters: Mapping[str, Any]) -> dict[str, Any]:
    """The ``/run/signals`` message of a published log (module docstring)."""
    from labrunner.logs.reader import read_run

    log = read_run(path)
    step = max(1, math.ceil(log.n_samples / MAX_SAMPLES))
    roles = {name: ch.get("role", "") for name, ch in log.channels.items()}
    units = {name: ch.get("unit", "") for name, ch in log.channels.items()}
    references = [n for n in log.names if roles.get(n) == "reference" or n.startswith("ref_")]
    tracked = references[0][len("ref_") :] if references else ""
    inputs = [n for n in log.names if roles.get(n) == "input"]
    names = {
        "output": tracked,
        "reference": references[0] if references else "",
        "error": f"e_{tracked}" if tracked else "",
        "input": inputs[0] if inputs else "",
    }
    signals = {name: _finite(log.data[i, ::step]) for i, name in enumerate(log.names)}
    run = {
        "point_id": point_id,
        "outcome": (log.outcome or {}).get("status", "torn"),
        "parameters": dict(parameters),
        "metrics": {k: _number(v) for k, v in log.metadata.get("metrics", {}).items()},
    }
    return _signals(run, log.fs, step, names, {n: units.get(n, "") for n in log.names}, signals)


def running_message(point_id: str, parameters: Mapping[str, Any], run: live.RunSignals) -> dict[str, Any]:
    """The ``/run/signals`` message of a run under way, from its slot of the live channel."""
    signals = {run.names[role]: _finite(row) for role, row in zip(live.ROLES, run.values)}
    about = {"point_id": point_id, "outcome": "running", "parameters": dict(parameters), "metrics": {}}
    return _signals(about, run.fs, run.step, run.names, run.units, signals)


def _signals(
    run: dict[str, Any],
    fs: float,
    step: int,
    names: Mapping[str, str],
    units: Mapping[str, str],
    signals: Mapping[str, list[float | None]],
) -> dict[str, Any]:
    """A ``/run/signals`` message: the run, its sampling, ``t`` and its signals, the four roles also by role."""
    n = len(next(iter(signals.values()), []))
    return {
        **run,
        "fs": fs,
        "rate_hz": fs / step,
        "decimation": step,
        "names": dict(names),
        "units": dict(units),
        "t": _finite(np.arange(0, n * step, step)[:n] / fs),
        **{role: signals.get(name, []) for role, name in names.items()},
        "signals": dict(signals),
    }


class LiveView:
    """The WebSocket server and its channels (module docstring); :func:`serve` opens one."""

    def __init__(self, address: Address, campaign: str, *, stream: TextIO | None = None) -> None:
        import foxglove

        self.campaign = campaign
        self.stream = stream or sys.stderr
        self._context = foxglove.Context()  # its own channels: not the process's global ones
        try:
            self.server = foxglove.start_server(
                name=f"labrunner {campaign}",
                host=address.host,
                port=address.port,
                context=self._context,
                message_backlog_size=BACKLOG,
            )
        except Exception as exc:  # the SDK raises its own error type for a port in use or a bad host
            raise CampaignError(f"--live: cannot listen on {address.host}:{address.port}: {exc}") from None
        self.channels = {
            topic: foxglove.Channel(topic, schema=schema, context=self._context) for topic, schema in SCHEMAS.items()
        }
        self.url = f"ws://{_bracketed(address.host)}:{self.server.port}"
        self._last_runs: deque[dict[str, Any]] = deque(maxlen=LAST_RUNS)
        self._next_progress = 0.0
        self._watched: tuple[str, int] | None = None  # the run under way last published, and its samples
        self._pending: tuple[Path, str, Mapping[str, Any]] | None = None
        self._wake = threading.Condition()
        self._closing = False
        self._failed = ""  # why the view stopped publishing ("": it has not)
        self._reader = threading.Thread(target=self._read_logs, name="labrunner-live", daemon=True)
        self._reader.start()
        print(f"live: {self.url}", file=self.stream, flush=True)
        if address.expose:
            print(
                f"live: exposed on {address.host}: any host that reaches port {self.server.port} sees this "
                "campaign's progress, every finished run's parameters, outcome and metrics, and run signals "
                "(no authentication, no encryption)",
                file=self.stream,
                flush=True,
            )

    def _log(self, topic: str, message: dict[str, Any]) -> None:
        channel = self.channels[topic]
        if channel.has_sinks():  # nobody subscribed: nothing to encode
            channel.log(message)

    @contextlib.contextmanager
    def _guarded(self) -> Iterator[None]:
        """What the scheduler calls must never stop the campaign: a failure of the view ends its
        publishing, with one line, and the campaign goes on."""
        try:
            yield
        except Exception as exc:
            self._failed = f"{type(exc).__name__}: {exc}"
            print(f"live: stopped publishing ({self._failed}); the campaign goes on", file=self.stream, flush=True)

    def progress(
        self, progress: Progress, watched: Callable[[], tuple[str, Any, live.RunSignals] | None] | None = None
    ) -> None:
        """The progress now, and the signals so far of the run ``watched()`` names (point id,
        parameters, signals), at most :data:`PROGRESS_HZ` times a second."""
        now = time.monotonic()
        if now < self._next_progress or self._failed:
            return
        with self._guarded():
            self._publish(progress, now, watched)

    def _publish(self, progress: Progress, now: float, watched: Callable[[], Any] | None) -> None:
        self._next_progress = now + 1.0 / PROGRESS_HZ
        self._progress(progress, now, False)
        run = watched() if watched is not None and self.channels["/run/signals"].has_sinks() else None
        if run is not None and (run[0], run[2].values.shape[1]) != self._watched:
            self._watched = (run[0], run[2].values.shape[1])
            self._log("/run/signals", running_message(*run))

    def ended(self, progress: Progress) -> None:
        """The session's last progress."""
        if not self._failed:
            with self._guarded():
                self._progress(progress, time.monotonic(), True)

    def _progress(self, progress: Progress, now: float, ended: bool) -> None:
        rate = progress.rate()
        left = progress.total - progress.position
        started = min(progress.taken if progress.taken is not None else progress.running, progress.running)
        self._log(
            "/campaign/progress",
            {
                "campaign": self.campaign,
                "total": progress.total,
                "finished": progress.finished,
                **{w.replace("-", "_"): progress.counts.get(w, 0) for w in FINISHED},
                "running": progress.running,
                "through_percent": 100.0 * min(progress.in_flight / started, 1.0) if started else 0.0,
                "runs_per_s": rate,
                "elapsed_s": now - progress.started,
                "eta_s": (0.0 if left <= 0 else left / rate) if rate > 0 or left <= 0 else None,
                "session_ended": ended,
            },
        )

    def finished(self, records: Sequence[Any], parameters: Mapping[str, Mapping[str, Any]], directory: Path) -> None:
        """A committed batch's records (:class:`~labrunner.campaign.ledger.RunRecord`), with
        their points' grid ``parameters`` by point id: each run's outcome and metrics; the signals
        of its representative run, or the nearest after it with a log (read in the view's thread)."""
        if not self._failed:
            with self._guarded():
                self._finished(records, parameters, directory)

    def _finished(self, records: Sequence[Any], parameters: Mapping[str, Mapping[str, Any]], directory: Path) -> None:
        for record in records:
            run = {
                "point_id": record.point_id,
                "outcome": record.outcome,
                "parameters": dict(parameters.get(record.point_id, {})),
                "metrics": {k: _number(v) for k, v in record.metrics.items()},
            }
            self._last_runs.appendleft(run)
            self._log("/campaign/run", run)
        if records:
            self._log("/campaign/last_runs", {"runs": list(self._last_runs)})
        middle = live.representative(len(records))
        first = next((r for r in [*records[middle:], *records[:middle]] if r.log_path), None)
        if first is not None and self.channels["/run/signals"].has_sinks():
            with self._wake:  # the newest replaces one not read yet
                self._pending = (directory / first.log_path, first.point_id, parameters.get(first.point_id, {}))
                self._wake.notify()

    def _read_logs(self) -> None:
        while True:
            with self._wake:
                while self._pending is None and not self._closing:
                    self._wake.wait()
                if self._closing:
                    return
                path, point_id, parameters = self._pending  # type: ignore[misc]
                self._pending = None
            try:
                message = signals_message(path, point_id, parameters)
            except Exception:  # a log gone or unreadable: the view skips it, the campaign is not its business
                continue
            self._log("/run/signals", message)

    def close(self) -> None:
        with self._wake:
            self._closing = True
            self._wake.notify()
        self._reader.join(timeout=5.0)
        self.server.stop()


def _bracketed(host: str) -> str:
    return f"[{host}]" if ":" in host else host


@contextlib.contextmanager
def serve(address: Address | None, campaign: str, stream: TextIO | None = None) -> Iterator[LiveView | None]:
    """A :class:`LiveView` at ``address`` for the block, or None without one (nothing listens)."""
    if address is None:
        yield None
        return
    view = LiveView(address, campaign, stream=stream)
    try:
        yield view
    finally:
        view.close()
