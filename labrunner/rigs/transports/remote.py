"""A real rig behind a frame link (:mod:`~labrunner.rigs.transports.protocol`): the host side, B = 1.

The device is the clock: ``step(u)`` sends the inputs of sample k and blocks until the device's
measurement of sample k arrives. A missing answer within ``timeout_s``, a dead transport or an
ERROR frame raises :class:`~labrunner.errors.RigError`, and the rig goes to its safe state first
(a SAFE frame, best effort: if it cannot be sent, the device's watchdog takes over).

Rig files of the remote kinds (``can``, ``serial``) name the ``device`` kind whose signals,
limits and nominal constants the rig has (``[parameters.model]`` holds that kind's parameters,
e.g. the motor's ``a`` and ``b`` for the stability overlays); ``RigInfo.kind`` is the device
kind and ``RigInfo.simulated`` is False.
"""

from __future__ import annotations

import abc
import time
from collections.abc import Mapping
from dataclasses import replace
from typing import Any, ClassVar

import numpy as np

from labrunner.errors import InvalidParameter, RigError
from labrunner.rigs.base import Faults, Rig, RigConfig, RigInfo
from labrunner.rigs.config import rig_info
from labrunner.rigs.kinds import rig_class, rig_kinds
from labrunner.rigs.schema import Param, validate_section
from labrunner.rigs.transports.protocol import FLAG_COMMIT, ErrorCode, Frame, Link, MsgType

COMMON = {
    "device": Param("dcmotor", "", "the kind of rig behind the link (any registered kind that is not itself remote)"),
    "node_id": Param(1, "", "the device's node id on the link", lo=0, hi=255),
    "timeout_s": Param(0.1, "s", "longest wait for a measurement beyond one sample period", lo=0.0, lo_open=True, hi=60.0),
}


class RemoteRig(Rig):
    """Host side of the rig protocol over any :class:`Link`; subclasses open the link from a rig file."""

    KIND: ClassVar[str]
    TRANSPORT: ClassVar[Mapping[str, Param]]

    def __init__(self, info: RigInfo, link: Link, timeout_s: float, faults: Faults | None = None) -> None:
        super().__init__(info, faults)
        self.link = link
        self.timeout_s = float(timeout_s)
        self._seq = 0

    # -- the Rig contract (no noise, no per-run parameters: the base class's defaults) ------------
    @classmethod
    def validate_parameters(cls, raw: Mapping[str, Any], path: str = "parameters") -> dict[str, Any]:
        """The link's keys, and ``[parameters.model]`` validated by the ``device`` kind's own schema."""
        raw = dict(raw)
        model = raw.pop("model", {})
        p = validate_section({**COMMON, **cls.TRANSPORT}, raw, path)
        try:
            device = rig_class(p["device"]) if p["device"] in rig_kinds() else None
        except InvalidParameter as exc:  # registered, but its module does not import here
            raise InvalidParameter(f"{path}.device", exc.message) from None
        if device is None or issubclass(device, RemoteRig):
            raise InvalidParameter(f"{path}.device", f"must be one of {device_kinds()}, got {p['device']!r}")
        if not isinstance(model, Mapping):
            raise InvalidParameter(f"{path}.model", f"must be a table, got {model!r}")
        p["model"] = device.validate_parameters(model, f"{path}.model")
        return p

    @classmethod
    def nominal_info(cls, name: str, description: str, parameters: Mapping[str, Any]) -> RigInfo:
        info = rig_class(parameters["device"]).nominal_info(name, description, parameters["model"])
        return replace(info, simulated=False, description=description or f"{info.kind} over {cls.KIND}")

    @classmethod
    def from_config(cls, config: RigConfig) -> RemoteRig:
        p = config.parameters
        return cls(rig_info(config), cls.open_link(p), p["timeout_s"], config.faults)

    @classmethod
    @abc.abstractmethod
    def open_link(cls, parameters: Mapping[str, Any]) -> Link:
        """Open the transport named by validated ``parameters`` (raises RigError)."""

    # -- Rig hooks -----------------------------------------------------------------------------
    def _reset(self, batch: int, seeds: np.ndarray, overrides: dict[str, np.ndarray]) -> np.ndarray:
        if batch != 1:
            raise InvalidParameter("batch", f"must be 1 for a real rig, got {batch}")
        while self.link.recv(0.0) is not None:  # drop what is left of an earlier run
            pass
        self._seq = 0
        self._send(Frame(MsgType.RESET, int(seeds[0]) % 2**32, value=self.fs))
        return self._collect(0)

    def _step(self, u: np.ndarray) -> np.ndarray:
        self._seq = (self._seq + 1) % 2**16
        n = u.shape[1]
        for ch in range(n):
            self._send(Frame(MsgType.INPUT, self._seq, ch, FLAG_COMMIT if ch == n - 1 else 0, float(u[0, ch])))
        return self._collect(self._seq)

    def _enter_safe_state(self, safe: np.ndarray) -> None:
        if safe.any():
            try:
                self.link.send(Frame(MsgType.SAFE, self._seq))
            except RigError:
                pass  # the device's watchdog puts it in its safe state when the host falls silent

    def _close(self) -> None:
        self.link.close()

    # -- helpers -------------------------------------------------------------------------------
    def _send(self, frame: Frame) -> None:
        try:
            self.link.send(frame)
        except RigError as exc:
            self._fail(str(exc))

    def _collect(self, seq: int) -> np.ndarray:
        """Wait for every output channel of sample ``seq``; ERROR frames and timeouts fail the rig."""
        n = len(self.info.outputs)
        y = np.zeros((1, n))
        missing = set(range(n))
        deadline = time.monotonic() + self.timeout_s + 1.0 / self.fs
        while missing:
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                self._fail(f"no measurement for sample {seq} within {self.timeout_s + 1.0 / self.fs:.3g} s")
            try:
                frame = self.link.recv(remaining)
            except RigError as exc:
                self._fail(str(exc))
            if frame is None:
                continue
            if frame.type == MsgType.ERROR:
                code = ErrorCode(frame.channel).name if frame.channel in ErrorCode._value2member_map_ else frame.channel
                self._fail(f"device error {code} (detail {frame.value:g})")
            if frame.type == MsgType.MEASUREMENT and frame.seq == seq and frame.channel < n:
                y[0, frame.channel] = frame.value
                missing.discard(frame.channel)
        return y

    def _fail(self, message: str) -> None:
        self.safe_state()
        raise RigError(f"rig {self.info.name!r}: {message}")


def device_kinds() -> list[str]:
    """The kinds a remote rig's ``device`` may name: every registered kind that is not remote itself."""
    kinds = []
    for kind in rig_kinds():
        try:
            remote = issubclass(rig_class(kind), RemoteRig)
        except InvalidParameter:  # a kind whose module cannot be imported here cannot be a device
            continue
        if not remote:
            kinds.append(kind)
    return sorted(kinds)
