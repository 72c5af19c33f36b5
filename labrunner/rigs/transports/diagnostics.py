"""Per-run diagnostics of a real rig: what the link dropped, what the host rejected, what the device said.

``RemoteRig.diagnostics()`` returns the record the worker stores as ``diagnostics`` in the run's
MCAP metadata and outcome (``docs/protocol.md`` § Diagnostics): the link's
:class:`~.link.LinkCounters` since the run's SETUP plus the host's :class:`HostCounters` and the
device's last STATUS counters. No frame counted here was ever used as data. Its timing counts
(late ticks, overruns) are read back by :mod:`labrunner.campaign.rig_timing`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

MAX_LISTED_TICKS = 100  # late/overrun tick indices listed in the record (the counts are complete)


@dataclass
class HostCounters:
    """What the host rejected or noticed in the measurements of one run."""

    stale: int = 0  # measurements of an earlier tick
    duplicate: int = 0  # a channel of the current tick received twice (the first is kept)
    bad_channel: int = 0  # a measurement channel beyond the rig's outputs
    lost_ticks: int = 0  # ticks abandoned with channels missing (the run fails; never committed)
    late_ticks: int = 0  # ticks the device flagged LATE: it held the previous input
    overruns: int = 0  # ticks the device flagged OVERRUN: its own clock slipped
    device_errors: int = 0  # ERROR frames from the device
    status_frames: int = 0  # device heartbeats (STATUS) received
    heartbeats_sent: int = 0  # host HEARTBEATs sent
    late_tick_indices: list[int] = field(default_factory=list)
    overrun_tick_indices: list[int] = field(default_factory=list)

    def note_tick(self, k: int, late: bool, overrun: bool) -> None:
        if late:
            self.late_ticks += 1
            if len(self.late_tick_indices) < MAX_LISTED_TICKS:
                self.late_tick_indices.append(k)
        if overrun:
            self.overruns += 1
            if len(self.overrun_tick_indices) < MAX_LISTED_TICKS:
                self.overrun_tick_indices.append(k)


@dataclass
class DeviceReport:
    """The device's own view, from its last STATUS (counters since the run's SETUP)."""

    state: int = -1  # DeviceState (-1: no STATUS yet)
    last_error: int = 0
    rejected: int = 0
    late: int = 0
    device_time_s: float = 0.0  # the last tick's device timestamp


def diagnostics_record(link: dict[str, int], host: HostCounters, device: DeviceReport, **extra: Any) -> dict[str, Any]:
    """The ``diagnostics`` record: ``{"link": {...}, "host": {...}, "device": {...}, ...extra}``."""
    return {"link": dict(link), "host": asdict(host), "device": asdict(device), **extra}
