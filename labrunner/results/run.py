"""One run's results from its log: signals with units and time, configuration, outcome, diagnostics.

The outcome has one shape for every run, twin or device (:data:`OUTCOME_KEYS`, None where a key
does not apply); a device loop's or a real rig's timing and link figures are the run's
``diagnostics`` (an empty dict for a twin run), never part of the outcome.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from labrunner import run_identity
from labrunner.logs import RunLog, read_run

if TYPE_CHECKING:
    import pandas as pd
    import xarray as xr

#: The keys of every run's :attr:`RunResults.outcome`, in this order.
OUTCOME_KEYS = ("status", "monitor", "time", "value", "threshold", "message", "n_samples")


def require_xarray():
    """The ``xarray`` module, or a one-line error saying how to install it (an optional dependency)."""
    try:
        import xarray
    except ImportError:
        raise ImportError(
            "labrunner's point × time results need xarray, which is not installed: "
            "pip install xarray (or pip install 'labrunner[results]')"
        ) from None
    return xarray


class RunResults:
    """One run log, read when first needed: ``signals`` (pandas, index ``t`` [s]), ``units``,
    ``config``, ``parameters``, ``outcome``, ``diagnostics``, ``metrics``, ``metadata``.

    Opened for a ledger row (``campaign.run(id)``: ``point_id`` and ``row``, the ledger's
    parameters, outcome and metrics), the log must back that row before anything of it is
    served: name that point (not a swapped or copied log), have every data chunk readable, and
    agree with the row (:func:`labrunner.run_identity.disagreement`); else reading it raises
    :class:`~labrunner.run_identity.ForeignLog` or :class:`~labrunner.run_identity.UntrustedLog`
    in one line. ``check=False`` serves it anyway, :attr:`problem` saying what is wrong."""

    def __init__(
        self,
        path: str | os.PathLike[str],
        point_id: str | None = None,
        *,
        row: Mapping[str, Any] | None = None,
        check: bool = True,
    ) -> None:
        self.path = Path(path)
        self.id = point_id if point_id is not None else self.path.stem
        self._expected = point_id
        self._row = row
        self._check = check

    def __repr__(self) -> str:
        """Point, outcome, samples and rate, start time, parameters, RMS error (from its log)."""
        from labrunner.results import describe

        return describe.text("RunResults", describe.run_facts(self))

    def _repr_html_(self) -> str:
        from labrunner.results import describe

        return describe.html_table("RunResults", describe.run_facts(self))

    @functools.cached_property
    def log(self) -> RunLog:
        """The run log as :func:`labrunner.logs.read_run` reads it (bit-exact samples), once it
        is shown to back its ledger row (see the class)."""
        log = read_run(self.path)
        kind, problem = self._problem_of(log)
        if problem and self._check:
            raise kind(f"{self.path}: {problem}; open it with check=False to read it anyway")
        self.__dict__["problem"] = problem
        return log

    @property
    def problem(self) -> str:
        """What is wrong with the log for its ledger row ("" if nothing, or not opened for a row)."""
        self.log  # noqa: B018 - reading it sets the problem
        return self.__dict__["problem"]

    def _problem_of(self, log: RunLog) -> tuple[type[Exception], str]:
        """(the error to raise, what is wrong with ``log`` for its row: "" if nothing)."""
        untrusted = run_identity.UntrustedLog
        if self._expected is not None:
            foreign = run_identity.mismatch(log.metadata, self._expected)
            if foreign:
                return run_identity.ForeignLog, foreign
        if log.damaged:
            return untrusted, f"damaged: {log.damaged}"
        if self._row is not None:
            differs = run_identity.disagreement(
                log.metadata,
                (log.outcome or {}).get("status"),
                self._row.get("parameters") or {},
                self._row.get("outcome"),
                self._row.get("metrics"),
            )
            if differs:
                return untrusted, f"disagrees with the ledger: {differs}"
        return untrusted, ""

    @property
    def fs(self) -> float:
        """Sampling rate [Hz]; sample k is at t = k / fs."""
        return self.log.fs

    @property
    def units(self) -> dict[str, str]:
        """SI unit of each signal (empty where the signal has none)."""
        return {name: str(info.get("unit") or "") for name, info in self.log.channels.items()}

    @property
    def roles(self) -> dict[str, str]:
        """Role of each signal: input, output, controlled, reference, error, estimate, signal."""
        return {name: str(info.get("role") or "") for name, info in self.log.channels.items()}

    @property
    def signals(self) -> pd.DataFrame:
        """One column per signal, index ``t`` [s]; ``.attrs["units"]`` maps columns to units. A
        copy: changing it leaves the run alone."""
        frame = self.log.frame.copy()
        frame.attrs["units"] = self.units
        frame.attrs["fs"] = self.fs
        return frame

    @property
    def metadata(self) -> dict[str, dict[str, Any]]:
        """Every metadata record of the log but the outcome (``run``, ``config``, ``rig``, ...)."""
        return self.log.metadata

    @property
    def config(self) -> dict[str, Any]:
        """The run's resolved configuration (controller, differentiator, reference, safety, ...)."""
        return dict(self.metadata.get("config") or {})

    @property
    def parameters(self) -> dict[str, Any]:
        """The grid point's parameters (dotted keys, as the table's columns name them)."""
        return dict(self.metadata.get("parameters") or {})

    @property
    def metrics(self) -> dict[str, Any]:
        """The metrics committed with the run (whole run and named windows), named as in the
        table: a run cut short (aborted, failed) has ``rms_error_until_abort`` etc., not ``rms_error``."""
        from labrunner.metrics import as_reported

        return as_reported(self.metadata.get("metrics") or {}, (self.log.outcome or {}).get("status"))

    @property
    def campaign_metadata(self) -> dict[str, Any]:
        """Its campaign's ``[metadata]`` as the log keeps it (operator, sample, notes, tags, …; {} without)."""
        return dict(self.metadata.get("metadata") or {})

    @property
    def diagnostics(self) -> dict[str, Any]:
        """A real rig's or device loop's record of the run (timing, link counters); {} for a twin."""
        return dict(self.metadata.get("diagnostics") or {})

    @property
    def outcome(self) -> dict[str, Any]:
        """How the run ended, :data:`OUTCOME_KEYS` (None where a key does not apply; status None:
        the log is torn, the run never finished)."""
        record = dict(self.log.outcome or {})
        record.pop("diagnostics", None)  # logs written before diagnostics were kept apart
        out = {key: record.pop(key, None) for key in OUTCOME_KEYS}
        if out["message"] is None:
            out["message"] = ""
        if out["n_samples"] is None:
            out["n_samples"] = self.log.n_samples
        return {**out, **record}

    def plot(self, *, size: str = "screen"):
        """The run's plot as ``labrunner plot`` draws it (a matplotlib Figure), ``size`` "screen"
        (7.5 in), "column" (3.5 in) or "page" (7.16 in) wide."""
        from labrunner.results.plots import run_figure

        return run_figure(self, size=size)

    def to_xarray(self) -> xr.Dataset:
        """The signals as an xarray Dataset over ``time`` [s], each variable's ``units`` attribute set."""
        xr = require_xarray()
        log = self.log
        units = self.units
        data = {
            name: ("time", log.data[j], {"units": units.get(name, ""), "role": self.roles.get(name, "")})
            for j, name in enumerate(log.names)
        }
        attrs = {"point_id": self.id, "fs": self.fs, "status": self.outcome["status"] or "torn"}
        return xr.Dataset(data, coords={"time": ("time", log.t, {"units": "s"})}, attrs=attrs)
