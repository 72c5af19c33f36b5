"""``labrunner check-rig``: what a real rig's link can do, measured before a campaign relies on it.

Handshake (the device's identity), round trips of N HEARTBEAT → STATUS pings, the link's and
the device's error counters, the link load of both loop placements at the rig's f_s (from the
load model, :mod:`~labrunner.rigs.transports.linkload`) and the highest f_s
the host loop sustains with margin: a host-loop tick needs one round trip (the measurement to
the host, the input back), so with half a period of margin for the host's own work
``f_max = 0.5 / p99(round trip)``, and no more than the load model allows. The device loop's
stream counts every column a run sends (:mod:`labrunner.rigs.device.columns`: u, y, the
controlled outputs computed from y, the references, the estimates) of a campaign's first point
at its f_s; without a campaign, the inputs and outputs alone (a lower bound).
"""

from __future__ import annotations

import json
import shutil
import subprocess
from typing import Any

import numpy as np

from labrunner.rigs.base import RigConfig
from labrunner.rigs.config import rig_info
from labrunner.rigs.device.columns import column_names
from labrunner.rigs.transports import linkload, messages as m

RTT_MARGIN = 0.5  # share of a period a host-loop round trip may take


def socketcan_bitrate(channel: str) -> int | None:
    """The bit rate the kernel set on a socketcan interface (``ip -details link``), or None."""
    if not channel or shutil.which("ip") is None:
        return None
    try:
        out = subprocess.run(
            ["ip", "-details", "-json", "link", "show", channel], capture_output=True, text=True, timeout=5, check=True
        ).stdout
        return int(json.loads(out)[0]["linkinfo"]["info_data"]["bittiming"]["bitrate"])
    except (OSError, subprocess.SubprocessError, ValueError, KeyError, IndexError, TypeError):
        return None


def streamed_columns(config: RigConfig, campaign_path: str | None) -> dict[str, Any]:
    """The columns a device-loop run streams per tick and the f_s they stream at: of the first
    point of the campaign at ``campaign_path`` on this rig, else the rig's inputs and outputs at
    its default f_s (InvalidParameter: a campaign whose point does not build on this rig)."""
    info = rig_info(config)
    if campaign_path is None:
        names = [s.name for s in (*info.inputs, *info.outputs)]
        return {"fs": info.fs_default, "columns": names, "from": "inputs and outputs (no campaign)"}
    from labrunner.campaign import spec
    from labrunner.control import factory
    from labrunner.engine import channel_names

    campaign = spec.load(campaign_path)
    _, point = next(campaign.points())
    controller, _ = factory.build([point], info, campaign.fs)
    names = column_names(channel_names(info, controller))
    return {"fs": campaign.fs, "columns": names, "from": f"campaign {campaign.name}, first point"}


def _link_load(config: RigConfig, stream: dict[str, Any], n_in: int, n_out: int, bitrate: float) -> dict[str, Any]:
    """Both placements' loads at the stream's f_s from the load model, on the link the rig file
    names at ``bitrate``, the device loop streaming the ``stream``'s columns."""
    spec = linkload.from_rig(config.kind, {**config.parameters, "bitrate": bitrate})
    return {
        "link": linkload.describe(spec),
        **linkload.report(spec, stream["fs"], n_in, n_out, len(stream["columns"])).as_dict(),
        "max_host_fs_by_load": linkload.max_host_fs(spec, n_in, n_out),
        "stream_columns": stream["columns"],
        "stream_columns_from": stream["from"],
    }


def check_rig(
    config: RigConfig,
    pings: int = 200,
    campaign: str | None = None,
    dead_time: bool = False,
    step: float | None = None,
) -> dict[str, Any]:
    """Open the rig, handshake, ping it ``pings`` times; the report as a JSON-friendly dict
    (the device loop's stream counted for ``campaign``'s first point, see :func:`streamed_columns`).
    ``dead_time``: also run the dead-time step (:mod:`.deadtime`; it moves the rig) of ``step``."""
    stream = streamed_columns(config, campaign)  # a bad campaign is refused before the rig opens
    from labrunner.rigs.registry import load_rig

    rig = load_rig(config)
    try:
        ident = rig.handshake()
        rtt = np.array([rig.ping() for _ in range(pings)])
        counters = rig.link.counters.as_dict()
        device = {
            "state": m.DeviceState(rig.device.state).name.lower() if rig.device.state >= 0 else None,
            "rejected": rig.device.rejected,
            "last_error": m.ErrorCode(rig.device.last_error).name,
        }
        if dead_time:
            from labrunner.rigs.transports.deadtime import dead_time as measure

            delay = measure(config, rig, step)
    finally:
        rig.close()
    p = config.parameters
    report: dict[str, Any] = {
        "rig": config.name,
        "source": config.source,
        "transport": config.kind,
        "node_id": p["node_id"],
        "loop": p["loop"],
        "identity": {
            "protocol_version": ident.version,
            "device_kind": m.DeviceKind(ident.device_kind).name.lower(),
            "inputs": ident.n_inputs,
            "outputs": ident.n_outputs,
            "max_fs": ident.max_fs,
            "capabilities": [c.name for c in m.Capability if ident.capabilities & c],
            "firmware_id": f"0x{ident.firmware_id:08x}",
        },
        "rtt_ms": {
            "pings": pings,
            "p50": 1e3 * float(np.percentile(rtt, 50)),
            "p99": 1e3 * float(np.percentile(rtt, 99)),
            "max": 1e3 * float(rtt.max()),
        },
        "link_counters": counters,
        "device": device,
    }
    bitrate = p.get("bitrate") or p.get("baudrate")
    if config.kind == "can":
        report["bitrate"] = {"configured": p["bitrate"], "interface": p["interface"] or "python-can config"}
        if p["interface"] == "socketcan":
            report["bitrate"]["socketcan"] = actual = socketcan_bitrate(p["channel"])
            bitrate = actual or bitrate
    else:
        report["baudrate"] = p["baudrate"]
    load = _link_load(config, stream, ident.n_inputs, ident.n_outputs, float(bitrate))
    report["link_load"] = load
    report["max_host_fs"] = min(RTT_MARGIN / float(np.percentile(rtt, 99)), load["max_host_fs_by_load"], ident.max_fs)
    if dead_time:
        report["dead_time"] = delay
    return report


def describe(report: dict[str, Any]) -> list[str]:
    """The report as lines for a terminal."""
    i, r = report["identity"], report["rtt_ms"]
    lines = [
        f"rig {report['rig']} ({report['source']}): {report['transport']} node {report['node_id']}, loop = {report['loop']}",
        f"  device: {i['device_kind']} protocol v{i['protocol_version']}, {i['inputs']} in / {i['outputs']} out, "
        f"max f_s {i['max_fs']:g} Hz, {'+'.join(i['capabilities']) or 'no capabilities'}, firmware {i['firmware_id']}",
        f"  round trip over {r['pings']} pings: p50 {r['p50']:.3f} ms, p99 {r['p99']:.3f} ms, max {r['max']:.3f} ms",
    ]
    if "bitrate" in report:
        b = report["bitrate"]
        actual = f", socketcan reports {b['socketcan']}" if "socketcan" in b else ""
        lines.append(f"  bit rate: {b['configured']} bit/s configured ({b['interface']}){actual}")
    bad = {k: v for k, v in report["link_counters"].items() if v and k not in ("sent", "received", "echoes")}
    lines.append(
        f"  link counters: {', '.join(f'{k} {v}' for k, v in bad.items()) or 'no errors'}; "
        f"device rejected {report['device']['rejected']}, last error {report['device']['last_error']}"
    )
    ld = report["link_load"]
    lines.append(
        f"  link load at {ld['fs']:g} Hz on {ld['link']}: host loop {ld['host_load']:.0%}"
        f"{'' if ld['host_feasible'] else ' (too much)'}, device-loop stream of {len(ld['stream_columns'])} "
        f"columns ({ld['stream_columns_from']}) {ld['device_stream_load']:.0%}"
        f"{'' if ld['device_streams'] else ' (sent after the run)'}"
    )
    lines.append(f"  the host loop sustains up to {report['max_host_fs']:.0f} Hz with margin")
    if "dead_time" in report:
        d = report["dead_time"]
        after = ", ".join(
            f"{who} moves {d[key] * 1e3:.3g} ms after it" if d[key] is not None else f"{who} does not move"
            for who, key in (("the rig", "rig_motion_after_s"), ("the twin", "twin_motion_after_s"))
        )
        lines.append(f"  dead time ({d['output']}, a step of the input to {d['step']:g}): {after}")
        lines.append(f"  dead time: {d['verdict'].upper()} — {d['detail']}")
    return lines
