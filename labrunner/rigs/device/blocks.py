"""Bodies of the device-loop's bulk blocks (pure): what each block kind carries, byte by byte
(docs/device-loop.md, "Blocks").

Host → device: DESCRIPTION (a slice of the run description; FLAG_LAST on the final slice).
Device → host: ACCEPT (the description checked, the run starts), REJECT (reason, ASCII),
PROGRESS (ticks done, device time), SAMPLES (float32 rows of consecutive ticks), VERDICT (how the
run ended, device timing; FLAG_LAST: the run's last block).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

DESCRIPTION, ACCEPT, REJECT, PROGRESS, SAMPLES, VERDICT = range(1, 7)

SAMPLES_HEAD = struct.Struct("<IHHQ")  # first tick, ticks, columns, device time of the first tick [µs]
PROGRESS_BODY = struct.Struct("<IQ")  # ticks done, device time [µs]
ACCEPT_BODY = struct.Struct("<IH")  # ticks to run, columns per tick
VERDICT_HEAD = struct.Struct("<BBHIIIdddQQ")
# status, monitor length, message length, samples, ticks, overruns, time, value, threshold,
# device run time [µs], compute time [ns]

STATUSES = ("completed", "aborted", "no-motion", "failed")


def samples_per_block(body_limit: int, n_columns: int) -> int:
    """Ticks one SAMPLES block carries on a link whose blocks hold ``body_limit`` bytes."""
    n = (body_limit - SAMPLES_HEAD.size) // (4 * max(n_columns, 1))
    if n < 1:
        raise ValueError(f"a block of {body_limit} bytes cannot carry one tick of {n_columns} columns")
    return min(n, 0xFFFF)


def encode_samples(first: int, rows: np.ndarray, t_us: int) -> bytes:
    rows = np.ascontiguousarray(rows, "<f4")
    return SAMPLES_HEAD.pack(first, rows.shape[0], rows.shape[1], t_us) + rows.tobytes()


def decode_samples(body: bytes) -> tuple[int, np.ndarray, int]:
    """(first tick, rows (ticks, columns) float32, device time of the first tick [µs])."""
    first, n, cols, t_us = SAMPLES_HEAD.unpack_from(body)
    if len(body) != SAMPLES_HEAD.size + 4 * n * cols:
        raise ValueError(f"SAMPLES block of {len(body)} bytes for {n} × {cols} values")
    return first, np.frombuffer(body, "<f4", n * cols, SAMPLES_HEAD.size).reshape(n, cols), t_us


@dataclass(frozen=True)
class Verdict:
    """How a device run ended and the device's timing."""

    status: str
    n_samples: int
    ticks: int
    overruns: int
    monitor: str = ""
    time: float = math.nan
    value: float = math.nan
    threshold: float = math.nan
    message: str = ""
    device_us: int = 0  # device clock at the end of the run [µs]
    compute_ns: int = 0  # time the device spent computing the run [ns]

    def encode(self) -> bytes:
        monitor, message = self.monitor.encode("ascii")[:255], self.message.encode("utf-8")[:4096]
        head = VERDICT_HEAD.pack(
            STATUSES.index(self.status),
            len(monitor),
            len(message),
            self.n_samples,
            self.ticks,
            self.overruns,
            self.time,
            self.value,
            self.threshold,
            self.device_us,
            self.compute_ns,
        )
        return head + monitor + message

    @classmethod
    def decode(cls, body: bytes) -> Verdict:
        status, n_mon, n_msg, n, ticks, overruns, t, value, threshold, device_us, compute_ns = VERDICT_HEAD.unpack_from(
            body
        )
        at = VERDICT_HEAD.size
        monitor = body[at : at + n_mon].decode("ascii")
        message = body[at + n_mon : at + n_mon + n_msg].decode("utf-8", "replace")
        return cls(STATUSES[status], n, ticks, overruns, monitor, t, value, threshold, message, device_us, compute_ns)


def tick_us(k: int, fs: float) -> int:
    """Device time of tick ``k`` [µs] on a clock ticking at ``fs``."""
    return int(round(k * 1e6 / fs))
