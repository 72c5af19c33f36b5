"""Serial framing of protocol v1: ``0x00, COBS(node, code, payload, CRC-16), 0x00``.

Why COBS (consistent overhead byte stuffing) rather than a sync byte and a length: 0x00 appears
only as the frame delimiter, so after any garbage the receiver is back in step at the next 0x00
and loses at most the frame the garbage hit; a sync byte can also occur inside a payload, and a
receiver that locked on a false one must rescan. A sender starts each frame with a 0x00 too, so
line noise before a frame ends at that delimiter and costs no frame. The overhead is three bytes
per frame (payloads stay below 254 bytes) and an encoder is twenty lines of C. CRC-16/CCITT-FALSE (polynomial
0x1021, initial 0xFFFF, check value 0x29B1 for "123456789") guards node, code and payload.

``docs/protocol.md`` has a worked example.
"""

from __future__ import annotations

import binascii

from labrunner.rigs.transports.link import LinkCounters

SERIAL_MAX_PAYLOAD = 64
_MAX_BODY = 2 + SERIAL_MAX_PAYLOAD + 2  # node, code, payload, CRC
_MAX_ENCODED = _MAX_BODY + 1  # one COBS overhead byte below 254


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of ``data``: the standard library's CRC-CCITT (``binascii.crc_hqx``, the same
    polynomial, not reflected) started at 0xFFFF. Every frame is checked on both sides of a serial link,
    and a bitwise loop in Python cost 4 s of a conform run; tests/test_transports.py checks it against
    the bitwise definition."""
    return binascii.crc_hqx(data, 0xFFFF)


def cobs_encode(data: bytes) -> bytes:
    """COBS encoding of ``data`` (< 254 bytes), without the trailing 0x00 delimiter."""
    out = bytearray()
    for block in data.split(b"\x00"):
        out.append(len(block) + 1)
        out += block
    return bytes(out)


def cobs_decode(data: bytes) -> bytes:
    """Inverse of :func:`cobs_encode` (ValueError for an invalid encoding)."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        code = data[i]
        if code == 0 or i + code > n or 0 in data[i + 1 : i + code]:
            raise ValueError("bad COBS encoding")
        out += data[i + 1 : i + code]
        i += code
        if i < n:
            out.append(0)
    return bytes(out)


def encode_frame(node: int, code: int, payload: bytes) -> bytes:
    """The bytes of one serial frame, both delimiters included."""
    body = bytes((node, code)) + payload
    crc = crc16(body)
    return b"\x00" + cobs_encode(body + bytes((crc & 0xFF, crc >> 8))) + b"\x00"


class SerialDecoder:
    """Streaming decoder: feed bytes as they arrive, get ``(node, code, payload)`` triples.

    Bad frames (COBS errors, short frames, CRC mismatches, runs longer than any frame) are
    dropped and counted in ``counters``; their bytes count as garbage.
    """

    def __init__(self, counters: LinkCounters | None = None) -> None:
        self.counters = counters if counters is not None else LinkCounters()
        self._buf = bytearray()

    def feed(self, data: bytes) -> list[tuple[int, int, bytes]]:
        self._buf += data
        out: list[tuple[int, int, bytes]] = []
        while True:
            end = self._buf.find(0)
            if end < 0:
                if len(self._buf) > _MAX_ENCODED:  # no delimiter where one must be: garbage
                    self.counters.garbage_bytes += len(self._buf)
                    self._buf.clear()
                return out
            chunk = bytes(self._buf[:end])
            del self._buf[: end + 1]
            if chunk:
                frame = self._frame(chunk)
                if frame is not None:
                    out.append(frame)

    def _frame(self, chunk: bytes) -> tuple[int, int, bytes] | None:
        try:
            body = cobs_decode(chunk)
        except ValueError:
            body = b""
        if len(body) < 4 or len(chunk) > _MAX_ENCODED:
            self.counters.malformed += 1
            self.counters.garbage_bytes += len(chunk) + 1
            return None
        if crc16(body[:-2]) != body[-2] | body[-1] << 8:
            self.counters.crc_errors += 1
            self.counters.garbage_bytes += len(chunk) + 1
            return None
        return body[0], body[1], body[2:-2]
