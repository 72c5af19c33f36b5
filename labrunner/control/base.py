"""The one Controller interface: B independent runs advanced in lockstep, one tick at a time.

Template method (as :class:`labrunner.rigs.base.Rig`): the public :meth:`Controller.step`
computes the law through the backend's ``_law``, saturates the result to the per-run input
limits [u_min, u_max] (thesis Sec. 3.3, "Input saturation") and keeps the *applied* (saturated)
input in :attr:`Controller.u_applied`, which the model-free estimators use on the next tick, as on
the thesis's hardware. Backends never clip on their own.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence

import numpy as np

from labrunner._ufunc import clip
from labrunner.errors import InvalidParameter


class Controller(abc.ABC):
    """B runs of one control law with per-run gains; B = 1 is the real-rig case.

    Shapes: ``y`` (B, n_rig_outputs) the raw rig measurement; ``r`` (B, n_outputs, 4) the
    reference and its derivatives 1..3 at this tick; returned ``u`` (B, n_inputs), saturated.
    After each step, :attr:`controlled` (B, n_outputs) holds the controlled outputs computed from
    ``y`` (e.g. Ω from θ by the difference quotient) and :attr:`estimates` maps names (``f_hat``,
    ``e_hat``, ``de_hat``) to (B, n_outputs) arrays for logging; both are overwritten in place on
    the next tick, so copy them to keep them.
    """

    #: order n of the ultra-local model y⁽ⁿ⁾ = f + γu behind :attr:`estimates` (f̂ is in the
    #: output's unit per sⁿ); None for laws without one (open loop, feed-forward)
    model_order: int | None = None

    def __init__(
        self,
        output_names: Sequence[str],
        u_min: np.ndarray,
        u_max: np.ndarray,
        u_init: np.ndarray | None = None,
        output_units: Sequence[str] | None = None,
    ) -> None:
        self.u_min = np.array(u_min, dtype=float, ndmin=2)
        self.u_max = np.array(u_max, dtype=float, ndmin=2)
        if self.u_min.shape != self.u_max.shape:
            raise InvalidParameter(
                "controller.u_max", f"shape {self.u_max.shape} differs from u_min {self.u_min.shape}"
            )
        if np.any(self.u_min > self.u_max):
            raise InvalidParameter("controller.u_max", "must be >= u_min for every run")
        self.batch, self.n_inputs = self.u_min.shape
        self.output_names = tuple(output_names)
        self.n_outputs = len(self.output_names)
        #: SI unit per controlled output; "" where the rig's signal of the same name says it
        self.output_units = tuple(output_units) if output_units is not None else ("",) * self.n_outputs
        init = np.zeros(self.u_min.shape) if u_init is None else np.broadcast_to(u_init, self.u_min.shape)
        self._u_init = np.array(init, dtype=float)
        self.u_applied = self._u_init.copy()
        self.controlled = np.zeros((self.batch, self.n_outputs))
        self.estimates: dict[str, np.ndarray] = {}
        #: the estimates' arrays stacked (n, ...) in the order of :attr:`estimates`, when the law
        #: keeps them so (see :meth:`_set_estimates`): a log copies them in one go per tick
        self.estimate_block: np.ndarray | None = None

    def reset(self, y0: np.ndarray) -> None:
        """Start from the stationary measurement ``y0`` (B, n_rig_outputs); histories are pre-filled."""
        y0 = np.asarray(y0, dtype=float)
        if y0.ndim != 2 or y0.shape[0] != self.batch:
            raise InvalidParameter("y0", f"must have shape ({self.batch}, n_rig_outputs), got {y0.shape}")
        self.u_applied[...] = self._u_init
        self._reset(y0)

    def step(self, y: np.ndarray, r: np.ndarray) -> np.ndarray:
        """One tick: the law on (y[k], r[k]), saturated to [u_min, u_max]; returns a copy of u[k]."""
        clip(self._law(y, r), self.u_min, self.u_max, out=self.u_applied)
        return self.u_applied.copy()

    def _set_estimates(self, block: np.ndarray, names: Sequence[str]) -> None:
        """Publish the estimates kept side by side in ``block`` (one name per leading index)."""
        if len(names) != len(block):
            raise ValueError(f"{len(names)} estimate names for {len(block)} rows")
        self.estimate_block = block
        self.estimates = dict(zip(names, block))

    @abc.abstractmethod
    def _reset(self, y0: np.ndarray) -> None:
        """Reset internal state from the first measurement (B, n_rig_outputs)."""

    @abc.abstractmethod
    def _law(self, y: np.ndarray, r: np.ndarray) -> np.ndarray:
        """Unsaturated input (B, n_inputs); :attr:`u_applied` still holds u[k−1] here."""
