"""A campaign directory's results in Python: the metrics table from the ledger, selection by
parameters, each run's :class:`~labrunner.results.run.RunResults`, and the runs' signals as one
point × time xarray Dataset.

The table is the one ``labrunner analyse`` writes to ``report/metrics.csv`` — the same columns,
names and outcome-aware metrics (an aborted run's in ``<metric>_until_abort``) — built from the
ledger whether or not ``analyse`` ran (logs are read only for rows of old ledgers that hold no
metrics, reusing ``report/metrics.parquet`` where it still matches). One difference: ``log_path``
is absolute here, where metrics.csv gives it relative to ``report/``.
"""

from __future__ import annotations

import functools
import json
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from labrunner.campaign.ledger import Ledger, ledger_path
from labrunner.errors import InvalidParameter
from labrunner.results import conditions as conditions_mod
from labrunner.results.describe import column_units, logged_units
from labrunner.results.run import RunResults, require_xarray

if TYPE_CHECKING:
    import xarray as xr

#: Folder of ``analyse``'s outputs, whose metrics.parquet caches rows read from logs.
REPORT_DIR = "report"
#: The table's columns about the files behind a row rather than the run (the log's size and
#: mtime, the metrics' version): the table's last columns, as in metrics.csv.
HOUSEKEEPING = ("log_size", "log_mtime_ns", "metrics_version")


class CampaignResults:
    """The results of one campaign directory (``labrunner run`` output); reads only, safe while the
    campaign runs (the table is the ledger's state when :meth:`table` is first called; :meth:`refresh`
    reads it again)."""

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)
        # refuses a folder without a ledger, in one line; the checks that read every row run once,
        # when the table is built (at 10^6 points each pass reads a 1.1 GB ledger)
        with Ledger.open_readonly(self.directory, thorough=False) as ledger:
            self.meta = ledger.meta()
        self.name = self.meta.get("campaign") or self.directory.name

    def __repr__(self) -> str:
        """Name, description, rig, date, points by outcome, parameters (from the ledger: no table built)."""
        from labrunner.results import describe

        return describe.text("CampaignResults", describe.campaign_facts(self))

    def _repr_html_(self) -> str:
        from labrunner.results import describe

        return describe.html_table("CampaignResults", describe.campaign_facts(self))

    @property
    def metadata(self) -> dict[str, Any]:
        """The campaign file's ``[metadata]`` (operator, sample, notes, tags, …; {} without one)."""
        return dict(json.loads(self.meta.get("metadata") or "{}"))

    def refresh(self) -> None:
        """Forget the table read so far (a running campaign has moved on)."""
        self.__dict__.pop("_built", None)

    @functools.cached_property
    def _built(self) -> tuple[pd.DataFrame, list[dict[str, str]], list[str]]:
        from labrunner.analysis import selection, table as table_mod
        from labrunner.analysis.table_files import METRICS_PARQUET
        from labrunner.analysis.table_rows import verified_chunks

        campaign, _ = selection.load_campaign(self.meta, self.directory)
        units, limits = selection.rig_signals(campaign)
        with Ledger.open_readonly(self.directory, per_row=False) as ledger:
            first = ledger.db.execute("SELECT parameters FROM points ORDER BY seq LIMIT 1").fetchone()
            path = ledger_path(self.directory)
            with verified_chunks(ledger.db, path) as chunks:  # streamed: a chunk of rows at a time
                built = table_mod.build_table(
                    chunks,
                    self.directory,
                    cache=self.directory / REPORT_DIR / METRICS_PARQUET,
                    units=units,
                    limits=limits,
                )
        # every point has the grid's keys (dotted: section.key); the first row names them in order
        named = [k for k in (json.loads(first[0]) if first else {}) if k in built.frame.columns]
        parameters = [*named, *(c for c in built.frame.columns if "." in c and c not in named)]
        frame = table_mod.ordered(built.frame).assign(metrics_version=table_mod.METRICS_VERSION)  # as metrics.csv
        paths = frame["log_path"]  # made absolute as text, not a join a row (~8 us each)
        inside = str(self.directory.resolve()) + os.sep + paths
        frame = frame.assign(log_path=inside.where(~paths.str.startswith(os.sep).fillna(False).astype(bool), paths))
        frame = frame.reset_index(drop=True)
        known = selection.table_units(frame, self.directory, campaign)
        frame.attrs["units"] = column_units(frame, known, {**units, **logged_units(frame)})
        return frame, built.problems, parameters

    def table(self, *, housekeeping: bool = True) -> pd.DataFrame:
        """One row per grid point: ids, outcome, parameters (dotted keys), metrics (a copy); last,
        the :data:`HOUSEKEEPING` columns, left out with ``housekeeping=False``."""
        frame = self._built[0]
        return frame.copy() if housekeeping else frame.drop(columns=[c for c in HOUSEKEEPING if c in frame])

    @property
    def parameters(self) -> list[str]:
        """The parameter columns of the table (dotted keys: ``controller.k_p``)."""
        return list(self._built[2])

    @property
    def problems(self) -> list[dict[str, str]]:
        """Missing, unreadable and torn logs found while building the table."""
        return list(self._built[1])

    def select(self, where: Mapping[str, Any] | None = None, /, **by_name: Any) -> pd.DataFrame:
        """The table's rows matching every condition. Keys are column names (``"controller.k_p"``,
        ``"outcome"``) or, as keywords, a parameter's last part when unique (``k_p=10``). A value
        is matched exactly, a float to within 1e-9 relative (grid values are computed), and a
        number on no grid value of a parameter is refused naming the closest; ``near(x)`` (or
        ``near(x, tolerance)``) matches the grid value nearest x; a list, tuple, set, range, numpy
        array or generator matches any of its values, a ``slice(lo, hi)`` the closed range [lo, hi]
        (either end None: open), a callable gets the column and returns a boolean mask. See
        :mod:`labrunner.results.conditions`."""
        if where is not None and not isinstance(where, Mapping):
            raise InvalidParameter("where", f"must map column names to conditions, got {type(where).__name__}")
        conditions = {**(where or {}), **{self._column(k): v for k, v in by_name.items()}}
        frame = self._built[0]
        parameters = set(self.parameters)
        mask = np.ones(len(frame), dtype=bool)
        for column, wanted in conditions.items():
            if column not in frame.columns:
                raise InvalidParameter(column, f"is no column of the table; parameters: {self.parameters}")
            mask &= conditions_mod.mask(column, frame[column], wanted, grid=column in parameters)
        return frame[mask].copy()

    def _column(self, key: str) -> str:
        if key in self._built[0].columns:
            return key
        found = [p for p in self.parameters if p.rsplit(".", 1)[-1] == key]
        if len(found) != 1:
            why = f"matches {found}: name one in full" if found else f"is no column; parameters: {self.parameters}"
            raise InvalidParameter(key, why)
        return found[0]

    def run(self, point: str | int, *, check: bool = True) -> RunResults:
        """One run, by point id (or a prefix of it that only one id starts with) or by ``seq``; a
        point without a log (not run, or failed before writing one) is refused, naming its outcome.
        Its log is served only once it backs the ledger row (its point, its data whole, its
        parameters and outcome the ledger's; see :class:`RunResults`); ``check=False`` serves it
        anyway, ``run.problem`` saying why not."""
        frame = self._built[0]
        if isinstance(point, str):
            point = self._full_id(point)
        hit = frame[frame["seq"] == point] if isinstance(point, (int, np.integer)) else frame[frame["id"] == point]
        if hit.empty:
            raise InvalidParameter("point", f"{point!r} is no point of campaign {self.name!r}")
        row = hit.iloc[0]
        if not isinstance(row["log_path"], str):
            raise InvalidParameter("point", f"{row['id']} has no run log (outcome {row['outcome']})")
        return self.runs(hit, check=check)[0]

    def _full_id(self, prefix: str) -> str:
        """The point id ``prefix`` names: itself, or the one id that starts with it (as git's short
        hashes); an ambiguous prefix is refused, naming how many ids start with it."""
        ids = self._built[0]["id"]
        if not prefix or (ids == prefix).any():
            return prefix
        found = ids[ids.str.startswith(prefix)]
        if len(found) > 1:
            shown = ", ".join(found.head(3)) + (", ..." if len(found) > 3 else "")
            raise InvalidParameter("point", f"{prefix!r} starts {len(found)} point ids ({shown}): give more of it")
        return str(found.iloc[0]) if len(found) else prefix

    def runs(self, rows: pd.DataFrame | None = None, *, check: bool = True) -> list[RunResults]:
        """The runs of ``rows`` (default: the whole table) that have a log, in table order (each
        checked against its ledger row when read, unless ``check=False``: see :meth:`run`)."""
        rows = self._built[0] if rows is None else rows
        ids = [i for i, p in zip(rows["id"], rows["log_path"]) if isinstance(p, str)]
        ledger_rows = self._ledger_rows(ids)
        return [
            RunResults(p, i, row=ledger_rows.get(i), check=check)
            for i, p in zip(rows["id"], rows["log_path"])
            if isinstance(p, str)
        ]

    def _ledger_rows(self, ids: list[str]) -> dict[str, dict[str, Any]]:
        """The ledger's parameters, outcome and committed metrics of points ``ids`` (what their logs
        must agree with), read now: a ledger edited since the table was built is compared as it is."""
        out: dict[str, dict[str, Any]] = {}
        with Ledger.open_readonly(self.directory, verify=False) as ledger:
            for start in range(0, len(ids), 500):
                part = ids[start : start + 500]
                marks = ", ".join("?" * len(part))
                query = f"SELECT id, parameters, outcome, metrics_json FROM points WHERE id IN ({marks})"
                for r in ledger.db.execute(query, part):
                    out[r["id"]] = {
                        "parameters": json.loads(r["parameters"]),
                        "outcome": r["outcome"],
                        "metrics": json.loads(r["metrics_json"]) if r["metrics_json"] else None,
                    }
        return out

    def signals(
        self,
        rows: pd.DataFrame | None = None,
        names: Iterable[str] | None = None,
        *,
        check: bool = True,
        grid: bool = True,
    ) -> xr.Dataset:
        """The signals of ``rows``' runs (default: every run with a log) as one xarray Dataset over
        (``point``, ``time``), or, where the runs form a full grid (each combination of the values
        of the parameters that vary among them run once), over (*parameters*, ``time``), e.g.
        (``gamma``, ``k_p``, ``time``): a dimension per varying parameter, named by its last part
        when unique as in :meth:`select` (else in full), the point ids then a ``point`` coordinate
        over them. Runs missing from the grid (not run, failed without a log) or repeated keep the
        ``point`` dimension, as does ``grid=False``. Runs must share their rate and their signals;
        a run shorter than the longest (aborted, torn) is padded with NaN, and ``n_samples`` (per
        point) and ``valid`` (point × time) say which samples were logged. ``names``: the signals
        to keep (default all). The parameters and outcome are coordinates along ``point`` (on a
        grid: the others than the dimensions, over them). A log that does not back
        its ledger row (another point's, damaged, disagreeing: see :meth:`run`) is refused, naming
        it; with ``check=False`` it is kept and the ``problem`` coordinate says what is wrong.
        Loads every selected run into memory: select first for large campaigns."""
        xr = require_xarray()
        rows = self._built[0] if rows is None else rows
        runs = self.runs(rows, check=check)
        if not runs:
            raise InvalidParameter("rows", "select at least one point with a run log")
        logs = [r.log for r in runs]
        fs = {log.fs for log in logs}
        if len(fs) != 1:
            raise InvalidParameter("rows", f"runs of one sampling rate only, got {sorted(fs)} Hz")
        wanted = list(names) if names is not None else list(logs[0].names)
        for run, log in zip(runs, logs):
            if not set(wanted) <= set(log.names):
                missing = sorted(set(wanted) - set(log.names))
                raise InvalidParameter("names", f"run {run.id} logs no {missing}; it logs {list(log.names)}")
        length = max(log.n_samples for log in logs)
        counts = np.array([log.n_samples for log in logs], dtype=np.int64)
        time = np.arange(length) / fs.pop()
        valid = np.arange(length)[None, :] < counts[:, None]
        units = runs[0].units
        data = {}
        for name in wanted:
            block = np.full((len(logs), length), np.nan)
            for i, log in enumerate(logs):
                block[i, : log.n_samples] = log.signal(name)
            data[name] = (("point", "time"), block, {"units": units.get(name, "")})
        data["n_samples"] = ("point", counts)
        data["valid"] = (
            ("point", "time"),
            valid,
            {"description": "sample logged (False: padding after the run ended)"},
        )
        by_id = rows.set_index("id")
        ids = [r.id for r in runs]
        coords: dict[str, Any] = {"point": ids, "time": ("time", time, {"units": "s"})}
        if not check:
            coords["problem"] = ("point", np.array([r.problem for r in runs], dtype=object))
        for column in ["outcome", *self.parameters]:
            if column in by_id.columns:
                coords[column] = ("point", by_id.loc[ids, column].to_numpy())
        dataset = xr.Dataset(data, coords=coords, attrs={"campaign": self.name, "directory": str(self.directory)})
        dims = _grid_dims(by_id.loc[ids, [p for p in self.parameters if p in by_id.columns]]) if grid else []
        if not dims:
            return dataset
        short = {d: self._dimension_name(d) for d in dims}
        if len(dims) == 1:  # a plain index, which unstack refuses: the ids stay a coordinate along it
            gridded = dataset.swap_dims(point=dims[0]).sortby(dims[0])
        else:
            gridded = dataset.assign_coords(id=("point", ids)).set_index(point=dims).unstack("point")
            gridded = gridded.rename({"id": "point"})
        return gridded.rename(short).transpose(*short.values(), "time")

    def _dimension_name(self, parameter: str) -> str:
        """``parameter``'s last part where no other parameter shares it (``k_p``), else in full."""
        last = parameter.rsplit(".", 1)[-1]
        return last if [p.rsplit(".", 1)[-1] for p in self.parameters].count(last) == 1 else parameter

    def plot_map(self, metric: str = "rms_error", *, size: str = "screen", title: bool = True, facet: int = 1):
        """The map of ``metric`` (a table column ``analyse`` maps: ``rms_error``, ``input_energy``,
        ...) as ``analyse`` draws it, a matplotlib Figure: ``size`` "screen" (7.5 in), "column"
        (3.5 in) or "page" (7.16 in) wide; ``title`` False for none (:mod:`labrunner.results.plots`)."""
        from labrunner.results.plots import campaign_map

        return campaign_map(self, metric, size=size, title=title, facet=facet)


def open_campaign(directory: str | Path) -> CampaignResults:
    """Open a campaign directory's results (see :class:`CampaignResults`)."""
    return CampaignResults(directory)


def open_run(path: str | Path) -> RunResults:
    """Open one run log (``runs/<point id>.mcap``) as :class:`RunResults`."""
    return RunResults(path)


def _grid_dims(parameters: pd.DataFrame) -> list[str]:
    """The columns of ``parameters`` (one row a run) that vary, where the rows hold each combination
    of their values exactly once (a full grid); [] where they do not, or where none varies."""
    varying = [c for c in parameters.columns if parameters[c].nunique(dropna=False) > 1]
    if not varying or parameters[varying].isna().any(axis=None):
        return []
    sizes = [parameters[c].nunique() for c in varying]
    full = int(np.prod(sizes)) == len(parameters) and not parameters.duplicated(subset=varying).any()
    return varying if full else []
