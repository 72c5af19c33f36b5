"""Run logs: one MCAP file per run (signals, metadata, outcome), readable by any MCAP tool
(Foxglove's reader, @mcap/core, included: ``tests/test_logs_foxglove.py``).

``write_run`` writes a finished (simulated) run, ``RunLogWriter`` streams a run from a real rig,
``LogPrefix`` / ``BatchPrefixes`` hold what a batch's logs share (encoded once), ``read_run``
reads one back (salvaging torn files), ``read_metadata`` / ``read_outcome`` read the records alone,
fast enough for thousands of runs. Layout, metadata text and log times: :mod:`.writer`; schemas
and the per-sample channel's field names: :mod:`.schema`; the MCAP encoding itself:
:mod:`.mcap_writer`; rewriting the labrunner-3 logs Foxglove refuses: :mod:`.upgrade`.
"""

from labrunner.logs.reader import RunLog, read_metadata, read_outcome, read_run
from labrunner.logs.schema import BLOCK_SAMPLES, BLOCK_TOPIC, SAMPLES_TOPIC, sample_field
from labrunner.logs.writer import ROLES, STATUSES, BatchPrefixes, LogPrefix, RunLogWriter, normalise_channels, write_run

__all__ = [
    "BLOCK_SAMPLES",
    "BLOCK_TOPIC",
    "BatchPrefixes",
    "LogPrefix",
    "ROLES",
    "RunLog",
    "RunLogWriter",
    "SAMPLES_TOPIC",
    "STATUSES",
    "normalise_channels",
    "read_metadata",
    "read_outcome",
    "read_run",
    "sample_field",
    "write_run",
]
