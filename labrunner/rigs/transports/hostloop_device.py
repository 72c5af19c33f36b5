"""The emulated device's host-loop handlers: SETUP records, INPUT frames and the tick clock.

Timing (``docs/protocol.md`` § Host loop): the seed record of SETUP starts the run: the device
samples y_0 at t_0 and sends it. Tick k+1 comes at t_{k+1} = t_0 + (k+1)/f_s on the device's
clock: if every channel of u_k arrived and was committed before it, u_k is applied over
[t_k, t_{k+1}] (the twin's zero-order hold); otherwise the device holds the input it applied last,
flags tick k+1 LATE and drops u_k when it comes. A device that runs a tick more than one period
after its time flags it OVERRUN and slips its clock (the next tick one period after this one)
rather than running the missed ticks back to back, which no host could answer in time. In SAFE
the clock goes on with the safe input held (the twin's own safe state), until STOP or the watchdog. Unpaced (``Emulator.paced = False``), tick k+1 follows the
commit of u_k at once and is never late.
"""

from __future__ import annotations

import time

import numpy as np

from labrunner.rigs.transports import messages as m
from labrunner.rigs.transports.protocol import Frame, Kind


class HostLoopDevice:
    """The host-loop part of the emulated firmware, bound to one :class:`~.emulator.Emulator`."""

    def __init__(self, emulator) -> None:
        self.emu = emulator
        n_in = len(emulator.rig.info.inputs)
        self.n_out = len(emulator.rig.info.outputs)
        self.setup: dict[int, float | int] = {}
        self.k = 0  # the tick number (its low 16 bits are the frames' seq)
        self.ran = 0  # ticks run since SETUP: an unpaced device's clock (not k, which a test may move)
        self.period = 0.0
        self.t0 = self.next_tick = 0.0
        self.pending = np.zeros((1, n_in))  # u_k as it arrives
        self.applied = np.zeros((1, n_in))
        self.got: set[int] = set()
        self.committed = -1  # the tick whose input is complete and committed

    def on_setup(self, frame: Frame) -> None:
        record = m.unpack(frame)
        try:
            self.setup[record.index] = m.setup_value(record)
        except ValueError:
            self.emu.rejected += 1
            self.emu.error(m.ErrorCode.BAD_SETUP, float(record.index), go_safe=False)
            return
        if record.index == m.SETUP_SEED:
            self._start()

    def _start(self) -> None:
        emu, s = self.emu, self.setup
        fs, watchdog = s.get(m.SETUP_FS, 0.0), s.get(m.SETUP_WATCHDOG, 0.0)
        lo, hi = emu.rig.info.fs_range
        if not (lo <= fs <= hi and watchdog > 0.0):
            emu.error(m.ErrorCode.BAD_SETUP, float(fs))
            return
        seed = int(s[m.SETUP_SEED])
        self.setup = {}
        y = emu.rig.reset(1, [seed], float(fs))
        emu.begin_run(watchdog)
        self.k, self.ran, self.period, self.committed, self.got = 0, 0, 1.0 / fs, -1, set()
        self.applied = np.asarray([emu.rig.info.safe_input], dtype=float)
        self.pending = self.applied.copy()
        self.t0 = time.monotonic()
        self.next_tick = self.t0 + self.period
        self._send(y, 0, 0)

    def on_input(self, frame: Frame) -> None:
        emu = self.emu
        if not emu.ticking:
            emu.rejected += 1
            if emu.state == m.DeviceState.IDLE:
                emu.error(m.ErrorCode.NOT_RUNNING, go_safe=False)
            return
        msg = m.unpack(frame)
        age = (self.k - msg.seq) % 2**16
        if 0 < age < 2**15 or (age == 0 and self.committed == self.k):  # late or repeated: dropped
            emu.rejected += 1
            return
        if age != 0:
            emu.error(m.ErrorCode.SEQUENCE, float(msg.seq))
            return
        if msg.channel >= self.pending.shape[1]:
            emu.error(m.ErrorCode.BAD_CHANNEL, float(msg.channel))
            return
        self.pending[0, msg.channel] = msg.value
        self.got.add(msg.channel)
        if msg.flags & m.FLAG_COMMIT:
            if len(self.got) == self.pending.shape[1]:
                self.committed = self.k
            else:  # a channel of this tick was lost: never apply a mix of old and new inputs
                emu.rejected += 1
            if not emu.paced:
                self._tick(time.monotonic())

    def clock(self, now: float) -> float | None:
        """The tick task of a paced device: run every tick that is due."""
        if not self.emu.paced or not self.emu.ticking:
            return None
        if now >= self.next_tick:
            self._tick(now)
            # a tick more than a period late slips the clock instead of running ticks back to back
            self.next_tick = now + self.period if now - self.next_tick > self.period else self.next_tick + self.period
        return self.next_tick

    def _tick(self, now: float) -> None:
        late = self.committed != self.k
        overrun = self.emu.paced and now - self.next_tick > self.period
        if late:
            self.emu.late += 1
        else:
            self.applied = self.pending.copy()
        y = self.emu.rig.step(self.applied)
        self.k += 1
        self.ran += 1
        self.emu.seq = self.k
        self.got = set()
        stamp = now - self.t0 if self.emu.paced else self.ran * self.period
        self._send(y, (m.FLAG_LATE if late else 0) | (m.FLAG_OVERRUN if overrun else 0), round(stamp * 1e6))

    def _send(self, y: np.ndarray, flags: int, stamp_us: int) -> None:
        send, seq = self.emu.link.send, self.k % 2**16
        for ch in range(self.n_out):
            send(m.pack(m.Measurement(seq, ch, 0, float(y[0, ch]))))
        send(m.pack(m.TickEnd(seq, m.TICK_CHANNEL, flags, stamp_us)))


def install(emulator) -> HostLoopDevice:
    """Register the host-loop handlers and the tick task on ``emulator``."""
    device = HostLoopDevice(emulator)
    emulator.handlers[Kind.SETUP] = device.on_setup
    emulator.handlers[Kind.INPUT] = device.on_input
    emulator.tasks.append(device.clock)
    emulator.host_loop = device
    return device
