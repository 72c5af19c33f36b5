"""Control laws for lab rigs: model-free control (MFC) of first and second order, baselines and
reference trajectories, all advancing B independent runs in lockstep (thesis ch. 2-3, papers 1-2).

- :mod:`~labrunner.control.base`: the :class:`Controller` interface.
- :mod:`~labrunner.control.trajectories`: poly-5 set points, steps, sines; batched :class:`Reference`.
- :mod:`~labrunner.control.estimators`: streaming f̂, ê, ê̇ (thesis (2.20), (2.25), (3.4)).
- :mod:`~labrunner.control.mfc`: ``mfc1``, ``mfc1-ff`` (Polack, k_p = 0), ``mfc2``.
- :mod:`~labrunner.control.baselines`: ``open-loop`` and ``valve-ffc`` (paper 1 eq. (11)).
- :mod:`~labrunner.control.plate`: ``plate-mfc`` (paper 2 eqs. (14)-(25), input variants, over-actuation);
  :mod:`~labrunner.control.plate_mbc` with :mod:`~labrunner.control.plate_filters`: ``plate-mbc``
  (paper 2 eqs. (7)-(12)); :mod:`~labrunner.control.plate_trajectories`: lift and tilt references.
- :mod:`~labrunner.control.factory`: kind registry, :func:`build` and :func:`validate` of campaign points.
"""

from labrunner.control.base import Controller
from labrunner.control.trajectories import Reference, Setpoints, Sine, Steps, Trajectory

__all__ = ["Controller", "Reference", "Setpoints", "Sine", "Steps", "Trajectory"]
