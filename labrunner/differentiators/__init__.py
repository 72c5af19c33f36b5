"""Algebraic differentiators (thesis Sec. 2.1; Othmane et al. 2022): design, FIR weights, spectra,
streaming and offline estimation. Pure numpy/scipy, no I/O.
"""

from labrunner.differentiators.design import METHODS, Differentiator, design
from labrunner.differentiators.spectra import amplitude_phase, continuous_response, cost_db, discrete_response
from labrunner.differentiators.streaming import History, StreamingFIR, estimate, pad_taps

__all__ = [
    "METHODS",
    "Differentiator",
    "History",
    "StreamingFIR",
    "amplitude_phase",
    "continuous_response",
    "cost_db",
    "design",
    "discrete_response",
    "estimate",
    "pad_taps",
]
