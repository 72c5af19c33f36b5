"""Run logs: one MCAP file per run (signals, metadata, outcome), readable by any MCAP tool.

``write_run`` writes a finished (simulated) run, ``RunLogWriter`` streams a run from a real rig,
``read_run`` reads one back (salvaging torn files), ``read_metadata`` / ``read_outcome`` read the
records alone, fast enough for thousands of runs. Layout and schemas: :mod:`.writer`, :mod:`.schema`;
the MCAP encoding itself: :mod:`.mcap_writer`.
"""

from labrunner.logs.reader import RunLog, read_metadata, read_outcome, read_run
from labrunner.logs.schema import BLOCK_SAMPLES, BLOCK_TOPIC, PREVIEW_HZ, PREVIEW_MAX_HZ, PREVIEW_TOPIC
from labrunner.logs.writer import ROLES, STATUSES, RunLogWriter, normalise_channels, write_run

__all__ = [
    "BLOCK_SAMPLES",
    "BLOCK_TOPIC",
    "PREVIEW_HZ",
    "PREVIEW_MAX_HZ",
    "PREVIEW_TOPIC",
    "ROLES",
    "RunLog",
    "RunLogWriter",
    "STATUSES",
    "normalise_channels",
    "read_metadata",
    "read_outcome",
    "read_run",
    "write_run",
]
