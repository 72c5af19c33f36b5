"""The device loop's laws as docs/control-laws.md writes them, tick by tick, in float64 or float32.

An implementation written from the document alone: plain per-tick code over a decoded run
description (the protocol's parser is the only labrunner code it uses; nothing of
labrunner.control, the engine or the safety monitor). Two uses:

* tests/test_vectors.py checks that it reproduces the shipped conformance vectors (float64), and
  tests/test_conform_reference.py puts it in the emulated device's place: a device built from
  the documents passes ``labrunner conform``;
* ``labrunner emulate --float32`` runs it in IEEE single precision, every operation on float32
  values (the arithmetic of a Cortex-M4F's FPU), so the host's float32 tolerance
  (docs/control-laws.md, "float32 devices") is tested without a C build.

:func:`run` takes a description and a ``measure(k, u_applied)`` callable (default: the
description's SENSOR_TABLE, row min(k, n − 1)) and returns what a device logs: per tick the
inputs, the measured outputs, the controlled outputs not measured, the references and the
estimates, and the verdict.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import numpy as np

from labrunner.rigs.device import f32bound
from labrunner.rigs.device.description import Description
from labrunner.rigs.device.f32bound import Bounded

#: ``measure(k, u)``: y[k] (float64), the rig having applied ``u`` (u[k−1]; the safe input before tick 0)
Measure = Callable[[int, np.ndarray], np.ndarray]


class _Arith:
    """Scalars and arrays in one arithmetic: every constant is rounded to it once, every result
    stays in it. ``dtype`` np.float64 or np.float32, or :class:`~.f32bound.Bounded` (the float64
    law carrying float32 rounding bounds: object arrays)."""

    def __init__(self, dtype: type) -> None:
        self.bounded = dtype is Bounded
        self.F = Bounded if self.bounded else np.dtype(dtype).type
        self.dtype = object if self.bounded else self.F

    def a(self, x) -> np.ndarray:
        if not self.bounded:
            return np.asarray(x, dtype=self.F)
        flat = [v if isinstance(v, Bounded) else Bounded(v) for v in np.ravel(np.asarray(x, dtype=object))]
        out = np.empty(len(flat), object)
        out[:] = flat
        return out.reshape(np.shape(x))

    def full(self, n: int, value) -> np.ndarray:
        return self.a([value] * n)

    def dot(self, w: np.ndarray, h: np.ndarray):
        if self.bounded:
            return f32bound.dot(w, h)
        return (w * h).sum(dtype=self.F)  # products and their (pairwise) sum in this type

    def clip(self, x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        if self.bounded:
            return self.a([f32bound.clip(*t) for t in zip(x, lo, hi)])
        return np.minimum(np.maximum(x, lo), hi)

    def relu(self, x: np.ndarray) -> np.ndarray:
        if self.bounded:
            return self.a([f32bound.relu(v) for v in x])
        return np.maximum(x, self.F(0))


def _poly5(tau, inside: bool, one):
    return (
        10 * tau**3 - 15 * tau**4 + 6 * tau**5,
        30 * tau**2 * (one - tau) ** 2,
        60 * tau * (one - tau) * (one - 2 * tau),
        60 * (one - 6 * tau + 6 * tau**2) if inside else 0 * one,
    )


def reference(code: int, arrays: list[np.ndarray], k: int, fs, ar: _Arith) -> list:
    """(r, ṙ, r̈, r⃛) of one TRAJECTORY record at tick k (t = k/f_s, each computed afresh)."""
    F = ar.F
    zero, one = F(0), F(1)
    t = F(k) / F(fs)
    if code == 1:
        first, starts, durations, steps = (ar.a(x) for x in arrays)
        out = [first[0], zero, zero, zero]
        for s, T, D in zip(starts, durations, steps):
            x = (t - s) / T
            p = _poly5(min(max(x, zero), one), zero <= x < one, one)
            for m in range(4):
                out[m] = out[m] + D * p[m] / T**m
        return out
    if code == 2:
        first, starts, steps = (ar.a(x) for x in arrays)
        level = first[0]
        for s, D in zip(starts, steps):
            if t >= s:
                level = level + D
        return [level, zero, zero, zero]
    if code == 3:
        A, w, D, offset, delay = ar.a(arrays[0])
        s = t - delay
        if not zero <= s < D:
            return [offset, zero, zero, zero]
        ws = w * s
        return [offset + A * np.sin(ws), A * w * np.cos(ws), -A * w**2 * np.sin(ws), -A * w**3 * np.cos(ws)]
    rows = arrays[1].reshape(-1, 4)  # the tick's row alone in the arithmetic: the whole table was O(n) a tick
    return list(ar.a(rows[min(k, len(rows) - 1)]))


SHARED_BYTES = 1024  #: a trajectory up to this size (setpoints, steps, a sine) is shared between runs; a table is not


def _reference_of(code: int, arrays: list[np.ndarray], fs, ar: _Arith, dtype: type) -> Callable[[int], list]:
    """k → :func:`reference` of one TRAJECTORY record. A small one is shared by every run that has it
    (:func:`_shared_reference`); a table is computed afresh, since looking it up would compare its
    bytes at every tick."""
    raw = tuple(a.tobytes() for a in arrays)
    if sum(map(len, raw)) > SHARED_BYTES:
        return lambda k: reference(code, arrays, k, fs, ar)
    return lambda k: list(_shared_reference(code, raw, k, fs, dtype))


@functools.lru_cache(maxsize=1 << 16)
def _shared_reference(code: int, raw: tuple[bytes, ...], k: int, fs: float, dtype: type) -> tuple:
    """:func:`reference` of the trajectory whose arrays' bytes are ``raw``, computed once per tick for
    every run that shares it: a rig's vectors (a conform run, a float32 bound) share their trajectory,
    and in the Bounded arithmetic the reference was 40 % of a vector's cost. Its numbers are the same
    objects, which no law changes in place."""
    return tuple(reference(code, [np.frombuffer(b) for b in raw], k, fs, _Arith(dtype)))


class Estimator:
    """f̂, ê, ê̇ of one ultra-local model of order n (docs/control-laws.md, "Model-free estimates")."""

    def __init__(self, w: list[np.ndarray], n: int, gamma_s, filter_error: bool, x0, ar: _Arith) -> None:
        self.w, self.n, self.gamma_s, self.filter_error, self.ar = w, n, gamma_s, filter_error, ar
        L = len(w[0])
        self.x = ar.full(L + 1, x0)  # newest first: x[k], x[k−1], …
        self.e = ar.full(L, ar.F(0) if filter_error else x0)
        self.v = ar.full(L, ar.F(0))  # v[k−1], v[k−2], …

    @staticmethod
    def _push(h: np.ndarray, value) -> None:
        h[1:] = h[:-1]
        h[0] = value

    def step(self, x, v_prev, r: list) -> tuple:
        self._push(self.x, x)
        self._push(self.v, v_prev)
        self._push(self.e, x - r[0] if self.filter_error else x)
        dot = self.ar.dot
        f = dot(self.w[self.n], self.x[1:]) - self.gamma_s * dot(self.w[0], self.v)
        e_hat = dot(self.w[0], self.e) - (0 if self.filter_error else r[0])
        de_hat = dot(self.w[1], self.e) - (0 if self.filter_error else r[1])
        return f, e_hat, de_hat


class Filter:
    """One channel of a FILTER record: [out, x⁺] = [x, w] · M, started in the steady state."""

    def __init__(self, M: np.ndarray, n: int, p: int, w0: np.ndarray, ar: _Arith) -> None:
        self.M, self.n, self.p = ar.a(M), n, p
        A, B = M[:n, p:].T, M[n:, p:].T  # the steady state in float64 (I − A is ill-conditioned), rounded once
        self.x = ar.a(np.linalg.solve(np.eye(n) - A, B @ w0.astype(float)) if n else np.zeros(0))

    def step(self, w: np.ndarray) -> np.ndarray:
        out = np.concatenate([self.x, w]) @ self.M
        self.x = out[self.p :]
        return out[: self.p]


def _filter(M: np.ndarray, n: int, p: int, w0: np.ndarray, ar: _Arith) -> Filter | f32bound.FilterBound:
    return f32bound.FilterBound(ar.a(M), n, p, w0) if ar.bounded else Filter(M, n, p, w0, ar)


def _filter_shape(d: Description, name: str) -> tuple[np.ndarray, int, int]:
    M = d.filters[name]
    p = {"_notch": 1, "_chain": 3}[name]
    return M, M.shape[1] - p, p


def table_sensor(d: Description) -> Measure:
    """The sensor-table mode: y[k] is the SENSOR_TABLE's row min(k, n − 1), whatever the input."""
    y_all = d.sensor_table
    return lambda k, u: y_all[min(k, len(y_all) - 1)]


def run(
    d: Description,
    inputs: list[str],
    outputs: list[str],
    dtype: type = np.float64,
    measure: Measure | None = None,
    tick: Callable[[int], None] | None = None,
) -> tuple[np.ndarray, dict[str, object]]:
    """(rows (n, columns) in SAMPLES order, verdict) of ``d`` computed in ``dtype``; ``tick(k)``
    every 32 ticks (an exception from it ends the run *failed* with its message)."""
    ar = _Arith(dtype)
    F = ar.F
    measure = measure or table_sensor(d)
    law = {k: ar.a(v) for k, v in d.law.items()}
    c = {k: v[0, 0] for k, v in law.items() if v.size == 1}
    u_min, u_max = (ar.a(x) for x in d.saturation)
    w = [ar.a(d.fir[(0, n)]) for n in range(3) if (0, n) in d.fir]
    n_in = len(inputs)
    u_prev = ar.full(n_in, F(0))
    rate_w = ar.a(d.fir[(1, 1)]) if (1, 1) in d.fir else None
    rate_hist = [ar.full(len(rate_w), F(0)) for _ in range(n_in)] if rate_w is not None else None  # safe input 0
    y0 = ar.a(measure(0, np.zeros(n_in)))
    state = _start(d, law, c, w, y0, ar)
    references = [_reference_of(code, arrays, d.fs, ar, dtype) for code, arrays in d.trajectories]
    rows, verdict = [], None
    try:
        for k in range(d.ticks):
            if tick is not None and k and k % 32 == 0:
                tick(k)
            y = y0 if k == 0 else ar.a(measure(k, np.array([float(v) for v in u_prev])))
            r = [at(k) for at in references]
            u, extra, est = _law(d, law, c, state, y, r, u_prev, ar)
            u = ar.clip(ar.a(u), u_min, u_max)
            extra = list(ar.clip(ar.a(extra), u_min, u_max)) if d.kind == "open-loop" else extra
            rates = []
            if rate_hist is not None:
                for h, v in zip(rate_hist, u):
                    Estimator._push(h, v if math.isfinite(float(v)) else F(0))
                rates = [abs(ar.dot(rate_w, h)) for h in rate_hist]
            rows.append([*u, *y, *extra, *(ri[0] for ri in r), *est])
            verdict = _safety(d, F(k) / F(d.fs), u, y, rates, inputs, outputs, ar)
            if verdict is not None:
                break
            u_prev = u
    except Exception as exc:  # the host's STOP, the watchdog, a dead link: the run fails, as a device's does
        verdict = {"status": "failed", "message": str(exc)}
    if verdict is None:
        j, rule, threshold = d.motion
        trace = [float(row[n_in + j]) for row in rows]
        moved = max(trace) > threshold if rule == 1 else max(abs(v - trace[0]) for v in trace) > threshold
        verdict = {"status": "completed" if moved else "no-motion"}
    if ar.bounded:
        verdict["bounds"] = f32bound.errors(np.array(rows, object).reshape(len(rows), -1))
    return np.array([[float(v) for v in row] for row in rows], dtype=float).reshape(len(rows), -1), verdict


def _start(d: Description, law: dict, c: dict, w: list[np.ndarray], y0: np.ndarray, ar: _Arith) -> dict:
    """The state before tick 0 (docs/control-laws.md, "Before tick 0")."""
    kind, state = d.kind, {}
    if kind in ("mfc1", "mfc1-ff", "mfc2"):
        n = 2 if kind == "mfc2" else 1
        o = int(c["output_index"])
        x0 = ar.F(0) if c["difference"] else y0[o]
        state["est"] = Estimator(w, n, c["gamma"], bool(c["filter_error"]), x0, ar)
        state["prev"] = y0[o]
    elif kind in ("plate-mfc", "plate-mbc"):
        K, lam = law["K"], c["lambda_inv_sqrt"]
        state["d"] = lam * (K @ y0[:3])
        state["h"] = K @ y0[:3]
        if kind == "plate-mfc":
            gamma, y_min = c["gamma"], c["y_min"]
            state["gy"] = ar.a([gamma / max(v, y_min) for v in y0[:3]])
            g_s = {0: gamma, 1: -gamma, 2: -gamma, 3: ar.F(-1)}[int(c["input"])]
            fe = bool(c["filter_error"])
            state["est"] = [Estimator(w, 2, g_s, fe, y0[j], ar) for j in range(3)]
            if "_notch" in d.filters:
                M, ns, p = _filter_shape(d, "_notch")
                state["notch"] = [_filter(M, ns, p, y0[j : j + 1], ar) for j in range(3)]
        else:
            M, ns, p = _filter_shape(d, "_chain")
            state["chain"] = [_filter(M, ns, p, ar.a([y0[j], c["g"]]), ar) for j in range(3)]
    return state


def _law(d: Description, law: dict, c: dict, s: dict, y, r: list, u_prev, ar: _Arith):
    """(unsaturated u, controlled outputs not measured, estimates) of one tick."""
    kind, F = d.kind, ar.F
    if kind == "open-loop":
        return [ri[0] for ri in r], [ri[0] for ri in r], []
    if kind == "valve-ffc":
        rho = np.sqrt(c["dp"]) if "dp" in c else np.sqrt(max(y[int(c["dp_index"])], F(0)))
        q_d = r[0][0] / F(60000)
        return [(c["kappa"] * q_d / rho if rho > 0 else F(0)) + c["i_0"]], [], []
    if kind in ("mfc1", "mfc1-ff", "mfc2"):
        o, gamma, n = int(c["output_index"]), c["gamma"], (2 if kind == "mfc2" else 1)
        if c["difference"]:
            x, s["prev"] = (y[o] - s["prev"]) * F(d.fs), y[o]
            extra = [x]
        else:
            x, extra = y[o], []
        f, e_hat, de_hat = s["est"].step(x, u_prev[0], r[0])
        u = (r[0][n] - f) / gamma - c["k_p"] / gamma * e_hat
        if n == 2:
            u = u - c["k_d"] / gamma * de_hat
        if "i_min" in c and r[0][0] <= 0:
            u = c["i_min"]
        return [u], extra, [f, e_hat] + ([de_hat] if n == 2 else [])
    K, V, PB, lam = law["K"], law["V"], law["P_inv_B"], c["lambda_inv_sqrt"]
    cy = y[:3]
    if kind == "plate-mbc":
        t = PB @ (u_prev / s["d"]) ** 2
        x_hat = [s["chain"][j].step(ar.a([cy[j], t[j] + c["g"]])) for j in range(3)]
        e = [x_hat[j][0] - r[j][0] for j in range(3)]
        de = [x_hat[j][1] - r[j][1] for j in range(3)]
        v = ar.a([r[j][2] - c["c_d"] * de[j] - c["c_p"] * e[j] - c["g"] - x_hat[j][2] for j in range(3)])
        s["d"] = lam * (K @ cy)
        u = s["d"] * np.sqrt(ar.relu(V @ v))
        return list(u), [], [*(x_hat[j][2] + c["g"] for j in range(3)), *e, *de]
    inp, gamma, a = int(c["input"]), c["gamma"], law["weights"][0]
    z = [s["notch"][j].step(cy[j : j + 1])[0] for j in range(3)] if "notch" in s else list(cy)
    if inp == 0:
        x_est = PB @ (u_prev / s["d"]) ** 2
    elif inp == 1:
        x_est = (u_prev[:3] / s["d"][:3]) ** 2
    elif inp == 2:
        x_est = (u_prev[:3] / s["h"][:3]) ** 2
    else:
        x_est = s["gy"] * u_prev[:3]
    fed = [s["est"][j].step(z[j], x_est[j], r[j]) for j in range(3)]
    wv = ar.a([r[j][2] - c["k_p"] * fed[j][1] - c["k_d"] * fed[j][2] - fed[j][0] for j in range(3)])
    s["d"], s["h"] = lam * (K @ cy), K @ cy
    s["gy"] = ar.a([gamma / max(v, c["y_min"]) for v in cy])
    if inp == 0:
        u = s["d"] * np.sqrt(ar.relu(V @ (wv / gamma)))
    else:
        x3 = -wv / (s["gy"] if inp == 3 else gamma)
        q = ar.a([*x3, ar.dot(a, x3)])
        u = q if inp == 3 else (s["d"] if inp == 1 else s["h"]) * np.sqrt(ar.relu(q))
    est = [*(f[0] for f in fed), *(f[1] for f in fed), *(f[2] for f in fed)]
    return list(u), [], est


def _safety(d: Description, t, u, y, rates, inputs, outputs, ar: _Arith) -> dict[str, object] | None:
    """The first monitor that trips at this tick (docs/control-laws.md, "Safety routine")."""

    def label(monitor: str, names: list[str], j: int) -> str:
        return monitor if len(names) == 1 else f"{monitor}:{names[j]}"

    def hit(monitor: str, value, threshold) -> dict[str, object]:
        return {"status": "aborted", "monitor": monitor, "time": float(t), "value": float(value),
                "threshold": float(threshold)}  # fmt: skip

    for monitor, values in (("non_finite_input", u), ("non_finite_output", y)):
        for v in values:
            if not math.isfinite(float(v)):
                return hit(monitor, v, 0.0)
    checks = []
    if 1 in d.bounds:
        checks.append((y, outputs, *d.bounds[1], "output"))
    if 2 in d.bounds and d.derived is not None:
        derived = list(ar.a(d.derived) @ y)
        checks.append((derived, [f"h{j + 1}" for j in range(len(derived))], *d.bounds[2], "output"))
    if 0 in d.bounds:
        checks.append((u, inputs, *d.bounds[0], "input"))
    order = []  # low before high within each group: measured outputs, derived outputs, inputs
    for values, names, lo, hi, group in checks:
        order.append((f"{group}_low", values, names, ar.a(lo), lambda v, b: v < b))
        order.append((f"{group}_high", values, names, ar.a(hi), lambda v, b: v > b))
    for monitor, values, names, bounds, over in order:
        for j, (v, b) in enumerate(zip(values, bounds)):
            if over(v, b):
                return hit(label(monitor, names, j), v, b)
    if d.rate is not None:
        limit = ar.F(d.rate[0])
        for j, rho in enumerate(rates):
            if rho >= limit:
                return hit(label("du_dt", inputs, j), rho, limit)
    if t >= d.max_duration:
        return hit("run_time", t, ar.F(d.max_duration))
    return None
