"""Closed loop of a plate controller (built by the factory from a campaign point) on the plate twin."""

import numpy as np

from labrunner.control.factory import build
from labrunner.rigs.registry import load_rig

FS = 32_000.0


def closed_loop(point, seconds=None, batch=1, rig_parameters=None, noise=None):
    """Run ``batch`` copies of ``point`` (or a list of points, one a run; run b's noise seed is b); return
    t (K,), y (K, B, 4), u (K, B, 4), r (K, B, 3), f_hat (K, B, 3)."""
    rig = load_rig({"rig": {"kind": "plate"}, "parameters": rig_parameters or {}, "noise": noise or {}})
    points = point if isinstance(point, list) else [point] * batch
    batch = len(points)
    controller, reference = build(points, rig.info, FS)
    K = int(round((reference.duration if seconds is None else seconds) * FS))
    t = np.arange(K) / FS
    R = reference.evaluate(t)
    y = rig.reset(batch, np.arange(batch), FS)
    controller.reset(y)
    Y, U, F = np.empty((K, batch, 4)), np.empty((K, batch, 4)), np.empty((K, batch, 3))
    for k in range(K):
        U[k] = controller.step(y, R[k])
        F[k] = controller.estimates["f_hat"]
        y = rig.step(U[k])
        Y[k] = y
    return {"t": t, "y": Y, "u": U, "r": R[:, :, :, 0], "f_hat": F}
