"""Link-load model: bits on the wire per frame and the load of each loop placement at f_s (pure).

Frame lengths (worst case, so a feasible plan stays feasible whatever the payload bits are):

* classic CAN, 11-bit identifier, ``n`` data bytes: ``34 + 8n + 13 + ⌊(34 + 8n − 1)/4⌋`` bits
  (Davis, Burns, Bril, Lukkien 2007, eq. (2): 34 stuffable header/CRC bits, 13 unstuffed bits of
  CRC delimiter, ACK, end of frame and interframe space, one stuff bit per 4 after the first);
  135 bits for 8 bytes.
* CAN FD, 11-bit identifier, bit-rate switch: the arbitration phase (SOF, identifier, RRS, IDE,
  FDF, res, BRS = 17 bits plus 4 stuff bits) and the tail (ACK, delimiters, EOF, IFS = 13 bits) at
  the nominal rate; ESI, DLC, data, stuff count and CRC (17 bits up to 16 bytes, else 21, each
  with its fixed stuff bits every 4) plus dynamic stuff bits of ESI..data at the data rate. The
  data length is rounded up to the next legal DLC size.
* serial (8N1): 10 bits per byte; a frame is ``serial_overhead`` framing bytes (delimiters, COBS
  byte, node, code, CRC-16) plus the payload.

Loads (fraction of the link's capacity, the busier direction of a full-duplex serial line, the
sum of both directions on a CAN bus, which is half-duplex):

* host loop (protocol v1, docs/protocol.md): per tick, one 8-byte INPUT frame per input host →
  device, one 8-byte MEASUREMENT frame per output and the tick's trailer device → host, on every
  medium (CAN FD sends them as 8-byte FD frames at the data rate);
* device loop: the sample stream of ``n_columns`` float32 per tick device → host in bulk frames
  (:mod:`~labrunner.rigs.transports.bulk`). It never makes the device loop infeasible: a stream
  that does not fit the budget is sent after the run, which then takes :func:`upload_s`.

A placement is feasible when its load is at most :data:`MAX_LOAD` (headroom for heartbeats,
retransmissions and other nodes on the bus).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

MAX_LOAD = 0.8  #: highest load a plan may put on a link
FD_SIZES = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)  #: legal CAN FD data lengths
VALUE_BYTES = 4  #: one float32 sample value
FIXED_BYTES = 8  #: payload of every host-loop frame
TRAILER_FRAMES = 1  #: the tick trailer (device timestamp, LATE/OVERRUN flags) after the measurements
BULK_FRAME_HEADER = 1  #: bytes of a bulk frame before its data (the frame index)
SAMPLE_BLOCK_OVERHEAD = 32  #: block header, sample-block header and CRC32 per sample block


@dataclass(frozen=True)
class LinkSpec:
    """A link: ``medium`` ∈ can | canfd | serial; ``bitrate`` [bit/s] (serial: baud; CAN FD: the
    nominal rate, ``data_bitrate`` the data phase's); ``max_payload`` [bytes] per frame."""

    medium: str
    bitrate: float
    data_bitrate: float = 0.0
    max_payload: int = 8
    serial_overhead: int = 7  # 0x00, COBS byte, node, code, CRC-16, 0x00 (framing.py)

    def __post_init__(self) -> None:
        if self.medium not in ("can", "canfd", "serial"):
            raise ValueError(f"medium must be can, canfd or serial, got {self.medium!r}")
        if not self.bitrate > 0:
            raise ValueError(f"bitrate must be > 0, got {self.bitrate!r}")

    @property
    def duplex(self) -> bool:
        """Whether both directions have their own capacity (a serial line: TX and RX wires)."""
        return self.medium == "serial"

    def frame_s(self, n: int) -> float:
        """Seconds on the wire of one frame with ``n`` payload bytes (worst-case stuffing)."""
        if n > self.max_payload:
            raise ValueError(f"payload of {n} bytes exceeds the link's {self.max_payload}")
        if self.medium == "can":
            return can_frame_bits(n) / self.bitrate
        if self.medium == "serial":
            return 10 * (self.serial_overhead + n) / self.bitrate
        nominal, data = canfd_frame_bits(n)
        return nominal / self.bitrate + data / (self.data_bitrate or self.bitrate)


def can_frame_bits(n: int) -> int:
    """Worst-case bits of a classic CAN data frame with an 11-bit identifier and ``n`` ≤ 8 bytes."""
    if not 0 <= n <= 8:
        raise ValueError(f"classic CAN carries 0..8 bytes, got {n}")
    return 34 + 8 * n + 13 + (34 + 8 * n - 1) // 4


def fd_length(n: int) -> int:
    """The smallest legal CAN FD data length ≥ ``n``."""
    for size in FD_SIZES:
        if size >= n:
            return size
    raise ValueError(f"CAN FD carries at most 64 bytes, got {n}")


def canfd_frame_bits(n: int) -> tuple[int, int]:
    """Worst-case (nominal-rate bits, data-rate bits) of a CAN FD frame with ``n`` ≤ 64 bytes."""
    size = fd_length(n)
    crc = 17 if size <= 16 else 21
    nominal = 17 + 4 + 13
    dynamic = 1 + 4 + 8 * size  # ESI, DLC, data
    data = dynamic + dynamic // 4 + 4 + crc + math.ceil((4 + crc) / 4)
    return nominal, data


def host_loop_load(link: LinkSpec, fs: float, n_inputs: int, n_outputs: int) -> float:
    """Load of the host loop at ``fs``: the inputs one way, the measurements and trailer the other."""
    per_tick = [n_inputs * link.frame_s(FIXED_BYTES), (n_outputs + TRAILER_FRAMES) * link.frame_s(FIXED_BYTES)]
    busy = max(per_tick) if link.duplex else sum(per_tick)
    return fs * busy


def bulk_bytes_s(link: LinkSpec, n_bytes: int) -> float:
    """Wire time of ``n_bytes`` of block data in full bulk frames."""
    per_frame = link.max_payload - BULK_FRAME_HEADER
    full, rest = divmod(n_bytes, per_frame)
    t = full * link.frame_s(link.max_payload)
    return t + (link.frame_s(BULK_FRAME_HEADER + rest) if rest else 0.0)


def sample_bytes(fs: float, duration: float, n_columns: int, samples_per_block: int = 256) -> int:
    """Bytes of the sample blocks of a run: float32 columns plus each block's overhead."""
    n = int(round(fs * duration))
    blocks = -(-n // samples_per_block)
    return n * n_columns * VALUE_BYTES + blocks * SAMPLE_BLOCK_OVERHEAD


def device_loop_load(link: LinkSpec, fs: float, n_columns: int) -> float:
    """Load of streaming a device loop's samples during the run (one second's worth per second)."""
    return bulk_bytes_s(link, sample_bytes(fs, 1.0, n_columns))


def upload_s(link: LinkSpec, fs: float, duration: float, n_columns: int) -> float:
    """Seconds to send a run's sample blocks after the run over an otherwise idle link."""
    return bulk_bytes_s(link, sample_bytes(fs, duration, n_columns))


@dataclass(frozen=True)
class LoadReport:
    """Loads of both placements at one f_s and what the device loop does with its samples."""

    fs: float
    host_load: float
    device_stream_load: float
    upload_s: float  # after-the-run transfer time of a ``duration`` run's samples

    @property
    def host_feasible(self) -> bool:
        return self.host_load <= MAX_LOAD

    @property
    def device_streams(self) -> bool:
        """Whether the device loop's samples fit the link during the run."""
        return self.device_stream_load <= MAX_LOAD

    def as_dict(self) -> dict[str, object]:
        return {
            "fs": self.fs,
            "host_load": self.host_load,
            "host_feasible": self.host_feasible,
            "device_stream_load": self.device_stream_load,
            "device_streams": self.device_streams,
            "upload_s": self.upload_s,
        }


def report(
    link: LinkSpec, fs: float, n_inputs: int, n_outputs: int, n_columns: int, duration: float = 1.0
) -> LoadReport:
    """Both placements' loads of a rig with these channel counts at ``fs``."""
    return LoadReport(
        float(fs),
        host_loop_load(link, fs, n_inputs, n_outputs),
        device_loop_load(link, fs, n_columns),
        upload_s(link, fs, duration, n_columns),
    )


def max_host_fs(link: LinkSpec, n_inputs: int, n_outputs: int) -> float:
    """The highest f_s [Hz] at which the host loop stays within :data:`MAX_LOAD`."""
    return MAX_LOAD / host_loop_load(link, 1.0, n_inputs, n_outputs)


def from_rig(kind: str, parameters: dict) -> LinkSpec:
    """The link a validated ``can`` or ``serial`` rig file's ``[parameters]`` name."""
    if kind == "serial":
        return LinkSpec("serial", float(parameters["baudrate"]), max_payload=64)
    if parameters.get("fd"):
        return LinkSpec("canfd", float(parameters["bitrate"]), float(parameters["data_bitrate"]), 64)
    return LinkSpec("can", float(parameters["bitrate"]))


def describe(link: LinkSpec) -> str:
    """The link in words for messages: "classic CAN at 1 Mbit/s"."""
    name = {"can": "classic CAN", "canfd": "CAN FD", "serial": "serial"}[link.medium]
    rate = f"{link.bitrate / 1e6:g} Mbit/s" if link.bitrate >= 1e6 else f"{link.bitrate / 1e3:g} kbit/s"
    if link.medium == "canfd" and link.data_bitrate:
        rate += f" ({link.data_bitrate / 1e6:g} Mbit/s data)"
    return f"{name} at {rate}"


def check_host_loop(link: LinkSpec, fs: float, n_inputs: int, n_outputs: int) -> str:
    """The one-line refusal of a host loop the link cannot carry at ``fs``, or "" when it can."""
    load = host_loop_load(link, fs, n_inputs, n_outputs)
    if load <= MAX_LOAD:
        return ""
    return (
        f"the host loop at {fs:g} Hz needs {load:.0%} of {describe(link)} (at most {MAX_LOAD:.0%}; it sustains "
        f'{max_host_fs(link, n_inputs, n_outputs):.0f} Hz): set loop = "device" in the rig file or lower campaign.fs'
    )
