"""``labrunner inspect RUN.mcap [--json]``: what a run log holds — outcome, samples, signals,
metadata — also for a torn file (its writer was killed) or a damaged one (a chunk unreadable, the
summary intact), which it says."""

from __future__ import annotations

import argparse
import json
from typing import Any

from labrunner.cli.argtypes import path_text


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "inspect",
        help="summarise one run log (MCAP)",
        description="Print a run log's outcome, sample count, rate, signals and metadata.",
    )
    parser.add_argument("path", type=path_text, metavar="RUN.mcap", help="run log to read")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(func=run)


def _short(value: Any, width: int = 100) -> str:
    text = json.dumps(value) if not isinstance(value, str) else value
    return text if len(text) <= width else text[: width - 3] + "..."


def format_summary(summary: dict[str, Any], path: str) -> str:
    """The human-readable form of :meth:`labrunner.logs.RunLog.summary`."""
    if summary["torn"]:
        lines = [path + "  [TORN: writer did not finish; complete chunks salvaged]"]
    elif summary.get("damaged"):
        lines = [path + f"  [DAMAGED: {summary['damaged']}; outcome and metadata read from the intact summary]"]
    else:
        lines = [path]
    outcome = summary["outcome"]
    if outcome is None:
        lines.append("outcome     none (run did not finish)")
    else:
        details = ", ".join(f"{k}={_short(v, 60)}" for k, v in outcome.items() if k != "status" and v not in (None, ""))
        lines.append(f"outcome     {outcome.get('status', '?')}" + (f"  ({details})" if details else ""))
    fs, n = summary["fs"], summary["n_samples"]
    duration = f", {n / fs:.4g} s" if isinstance(fs, float) and fs > 0 else ""
    lines.append(f"samples     {n} at {fs:g} Hz{duration}" if isinstance(fs, float) else f"samples     {n}")
    channels = summary["metadata"].get("channels", {})
    described = []
    for name in summary["signals"]:
        info = channels.get(name, {})
        unit = f" [{info['unit']}]" if info.get("unit") else ""
        described.append(f"{name}{unit} ({info.get('role', '?')})")
    lines.append("signals     " + ", ".join(described))
    for record, values in summary["metadata"].items():
        if record == "channels":
            continue
        lines.append(f"{record:<11} " + "; ".join(f"{k}={_short(v)}" for k, v in values.items()))
    if summary["attachments"]:
        lines.append("attachments " + ", ".join(f"{k} ({v} bytes)" for k, v in summary["attachments"].items()))
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from labrunner.logs import read_run
    from labrunner.metrics import as_reported

    summary = read_run(args.path).summary()
    metadata = summary["metadata"]
    if "metrics" in metadata:  # a run cut short: rms_error_until_abort, ..., as the table and the results API
        metadata["metrics"] = as_reported(metadata["metrics"], (summary["outcome"] or {}).get("status"))
    print(json.dumps(summary, indent=2) if args.json else format_summary(summary, args.path))
    return 0
