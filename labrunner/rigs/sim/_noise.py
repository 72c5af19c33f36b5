"""Per-run reproducible noise for batched twins without a Python loop over runs in a tick.

Run i draws from its own generator, seeded by ``SeedSequence([seed_i, stream])``, in blocks of
``block`` ticks; the loop over runs happens once per block, not per tick. Run i's noise therefore
depends only on its seed and the stream id: a batch of B runs sees exactly the noise of B single
runs with the same seeds. Runs with equal seeds (a campaign's, by default) share one generator:
the same numbers, drawn once.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from labrunner.errors import InvalidParameter


class NoiseStreams:
    """Normal draws of shape (B, width), one per :meth:`next` call (one per tick).

    Standard normal, or times ``scale`` (broadcast to (B, width): the noise levels per run and
    channel), applied once per block rather than once per tick. With ``groups`` = G, a tick's
    draws come as G contiguous (B, width/G) arrays (channels 0..width/G−1, then the next ones),
    the same numbers, each ready for a ufunc without strides.
    """

    def __init__(
        self,
        seeds: Sequence[int] | np.ndarray,
        width: int,
        stream: int,
        block: int = 512,
        scale: np.ndarray | float | None = None,
        groups: int = 1,
    ) -> None:
        seeds = np.asarray(seeds, dtype=np.int64).reshape(-1)
        self.batch = len(seeds)
        # one generator per distinct seed (a campaign's runs mostly share one), and its runs
        unique, run_of = np.unique(seeds, return_inverse=True)
        self._gens = [
            np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(s) % 2**64, stream]))) for s in unique
        ]
        self._runs = [np.flatnonzero(run_of.reshape(-1) == i) for i in range(len(unique))]
        self.width = int(width)
        self.block = int(block)
        self._scale = (
            None if scale is None else np.broadcast_to(np.asarray(scale, dtype=float), (self.batch, self.width))
        )
        if groups < 1 or self.width % groups:
            raise InvalidParameter("groups", f"must divide the width {self.width}, got {groups}")
        self.groups = groups
        self._buf = np.empty((0, groups, self.batch, self.width // groups))
        self._i = 0

    def next(self) -> np.ndarray:
        """The next tick's draws: (B, width), or (G, B, width/G) in groups; valid until the next block."""
        if self._i >= self._buf.shape[0]:
            G, B, per, K = self.groups, self.batch, self.width // self.groups, self.block
            if self._buf.shape[0] != K:
                self._buf = np.empty((K, G, B, per))
            for g, runs in zip(self._gens, self._runs):  # once per block, not per tick
                draws = g.standard_normal((K, 1, self.width))  # the same numbers for every run of this seed
                if self._scale is not None:
                    draws = draws * self._scale[runs]  # (K, n, width), each run at its own level
                draws = np.broadcast_to(draws, (K, len(runs), self.width))
                self._buf[:, :, runs, :] = draws.reshape(K, len(runs), G, per).transpose(0, 2, 1, 3)
            self._i = 0
        out = self._buf[self._i]
        self._i += 1
        return out if self.groups > 1 else out[0]
