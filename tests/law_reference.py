"""An independent implementation of the device loop's laws, written from docs/control-laws.md
alone: plain per-sample Python over a decoded run description (the protocol's parser is the only
labrunner code it uses; nothing of labrunner.control, the engine or the safety monitor).

:func:`run` takes a description with a SENSOR_TABLE and returns what a device would log: per
tick the inputs, the controlled outputs that are not measured, the references and the estimates,
and the verdict. tests/test_vectors.py checks it reproduces the shipped conformance vectors.
"""

from __future__ import annotations

import math

import numpy as np

from labrunner.rigs.device.description import Description


def _poly5(tau: float, inside: bool) -> tuple[float, float, float, float]:
    return (
        10 * tau**3 - 15 * tau**4 + 6 * tau**5,
        30 * tau**2 * (1 - tau) ** 2,
        60 * tau * (1 - tau) * (1 - 2 * tau),
        60 * (1 - 6 * tau + 6 * tau**2) if inside else 0.0,
    )


def reference(code: int, arrays: list[np.ndarray], k: int, fs: float) -> list[float]:
    """(r, ṙ, r̈, r⃛) of one TRAJECTORY record at tick k."""
    t = k / fs
    if code == 1:
        first, starts, durations, steps = arrays
        out = [float(first[0]), 0.0, 0.0, 0.0]
        for s, T, D in zip(starts, durations, steps):
            x = (t - s) / T
            p = _poly5(min(max(x, 0.0), 1.0), 0.0 <= x < 1.0)
            for m in range(4):
                out[m] += D * p[m] / T**m
        return out
    if code == 2:
        first, starts, steps = arrays
        return [float(first[0]) + sum(D for s, D in zip(starts, steps) if t >= s), 0.0, 0.0, 0.0]
    if code == 3:
        A, w, D, offset, delay = arrays[0]
        s = t - delay
        if not 0.0 <= s < D:
            return [offset, 0.0, 0.0, 0.0]
        return [
            offset + A * math.sin(w * s),
            A * w * math.cos(w * s),
            -A * w**2 * math.sin(w * s),
            -A * w**3 * math.cos(w * s),
        ]
    rows = arrays[1].reshape(-1, 4)
    return list(rows[min(k, len(rows) - 1)])


def _dot(w: np.ndarray, history: list[float]) -> float:
    return sum(float(a) * b for a, b in zip(w, history))


class Estimator:
    """f̂, ê, ê̇ of one ultra-local model of order n (docs/control-laws.md, "Model-free estimates")."""

    def __init__(self, w: list[np.ndarray], n: int, gamma_s: float, filter_error: bool, x0: float) -> None:
        self.w, self.n, self.gamma_s, self.filter_error = w, n, gamma_s, filter_error
        L = len(w[0])
        self.x = [x0] * (L + 1)  # newest first: x[k], x[k−1], …
        self.e = [0.0 if filter_error else x0] * L
        self.v = [0.0] * L  # v[k−1], v[k−2], …

    def step(self, x: float, v_prev: float, r: list[float]) -> tuple[float, float, float]:
        self.x = [x, *self.x[:-1]]
        self.v = [v_prev, *self.v[:-1]]
        self.e = [x - r[0] if self.filter_error else x, *self.e[:-1]]
        f = _dot(self.w[self.n], self.x[1:]) - self.gamma_s * _dot(self.w[0], self.v)
        e_hat = _dot(self.w[0], self.e) - (0.0 if self.filter_error else r[0])
        de_hat = _dot(self.w[1], self.e) - (0.0 if self.filter_error else r[1])
        return f, e_hat, de_hat


class Filter:
    """One channel of a FILTER record: [out, x⁺] = [x, w] · M, started in the steady state."""

    def __init__(self, M: np.ndarray, n: int, p: int, w0: np.ndarray) -> None:
        self.M, self.n, self.p = M, n, p
        A, B = M[:n, p:].T, M[n:, p:].T
        self.x = np.linalg.solve(np.eye(n) - A, B @ w0) if n else np.zeros(0)

    def step(self, w: np.ndarray) -> np.ndarray:
        out = np.concatenate([self.x, w]) @ self.M
        self.x = out[self.p :]
        return out[: self.p]


def _filter_shape(d: Description, name: str) -> tuple[np.ndarray, int, int]:
    M = d.filters[name]
    p = {"_notch": 1, "_chain": 3}[name]
    return M, M.shape[1] - p, p


def _c(d: Description, name: str) -> float:
    return float(d.law[name][0, 0])


def run(d: Description, inputs: list[str], outputs: list[str]) -> tuple[np.ndarray, dict[str, object]]:
    """(rows (n, columns) in SAMPLES order with the measured outputs as given, verdict) of ``d``."""
    y_all = d.sensor_table
    fs, kind = d.fs, d.kind
    u_min, u_max = d.saturation
    w = [d.fir[(0, n)] for n in range(3) if (0, n) in d.fir]
    n_in = len(inputs)
    u_prev = [0.0] * n_in
    rate_w = d.fir.get((1, 1))
    rate_hist = [[0.0] * len(rate_w) for _ in range(n_in)] if rate_w is not None else []  # safe input 0
    y0 = y_all[0]
    state: dict[str, object] = {}
    if kind in ("mfc1", "mfc1-ff", "mfc2"):
        n = 2 if kind == "mfc2" else 1
        o = int(_c(d, "output_index"))
        x0 = 0.0 if _c(d, "difference") else y0[o]
        state["est"] = Estimator(w, n, _c(d, "gamma"), bool(_c(d, "filter_error")), x0)
        state["prev"] = y0[o]
    elif kind in ("plate-mfc", "plate-mbc"):
        K, lam = d.law["K"], _c(d, "lambda_inv_sqrt")
        state["d"] = lam * (K @ y0[:3])
        state["h"] = K @ y0[:3]
        if kind == "plate-mfc":
            gamma, y_min = _c(d, "gamma"), _c(d, "y_min")
            state["gy"] = [gamma / max(v, y_min) for v in y0[:3]]
            g_s = {0: gamma, 1: -gamma, 2: -gamma, 3: -1.0}[int(_c(d, "input"))]
            fe = bool(_c(d, "filter_error"))
            state["est"] = [Estimator(w, 2, g_s, fe, y0[j]) for j in range(3)]
            if "_notch" in d.filters:
                M, ns, p = _filter_shape(d, "_notch")
                state["notch"] = [Filter(M, ns, p, np.array([y0[j]])) for j in range(3)]
        else:
            M, ns, p = _filter_shape(d, "_chain")
            state["chain"] = [Filter(M, ns, p, np.array([y0[j], _c(d, "g")])) for j in range(3)]
    rows, verdict = [], None
    for k in range(d.ticks):
        y = list(y_all[min(k, len(y_all) - 1)])
        r = [reference(code, arrays, k, fs) for code, arrays in d.trajectories]
        u, extra, est = _law(d, state, y, r, u_prev)
        u = [min(max(v, lo), hi) for v, lo, hi in zip(u, u_min, u_max)]
        extra = [min(max(v, lo), hi) for v, lo, hi in zip(extra, u_min, u_max)] if kind == "open-loop" else extra
        rates = []
        for j in range(len(rate_hist)):
            rate_hist[j] = [u[j] if math.isfinite(u[j]) else 0.0, *rate_hist[j][:-1]]
            rates.append(abs(_dot(rate_w, rate_hist[j])))
        rows.append([*u, *y, *extra, *(ri[0] for ri in r), *est])
        verdict = _safety(d, k / fs, u, y, rates, inputs, outputs)
        if verdict is not None:
            break
        u_prev = u
    if verdict is None:
        j, rule, threshold = d.motion
        trace = [row[n_in + j] for row in rows]
        moved = max(trace) > threshold if rule == 1 else max(abs(v - trace[0]) for v in trace) > threshold
        verdict = {"status": "completed" if moved else "no-motion"}
    return np.array(rows, dtype=float), verdict


def _law(d: Description, s: dict, y: list[float], r: list[list[float]], u_prev: list[float]):
    """(unsaturated u, controlled outputs not measured, estimates) of one tick."""
    kind = d.kind
    if kind == "open-loop":
        return [ri[0] for ri in r], [ri[0] for ri in r], []
    if kind == "valve-ffc":
        rho = math.sqrt(_c(d, "dp")) if "dp" in d.law else math.sqrt(max(y[int(_c(d, "dp_index"))], 0.0))
        q_d = r[0][0] / 60000.0
        return [(_c(d, "kappa") * q_d / rho if rho > 0 else 0.0) + _c(d, "i_0")], [], []
    if kind in ("mfc1", "mfc1-ff", "mfc2"):
        o, gamma, n = int(_c(d, "output_index")), _c(d, "gamma"), (2 if kind == "mfc2" else 1)
        if _c(d, "difference"):
            x, s["prev"] = (y[o] - s["prev"]) * d.fs, y[o]
            extra = [x]
        else:
            x, extra = y[o], []
        f, e_hat, de_hat = s["est"].step(x, u_prev[0], r[0])
        u = (r[0][n] - f) / gamma - _c(d, "k_p") / gamma * e_hat
        if n == 2:
            u -= _c(d, "k_d") / gamma * de_hat
        if "i_min" in d.law and r[0][0] <= 0:
            u = _c(d, "i_min")
        return [u], extra, [f, e_hat] + ([de_hat] if n == 2 else [])
    K, V, PB, lam = d.law["K"], d.law["V"], d.law["P_inv_B"], _c(d, "lambda_inv_sqrt")
    c = np.array(y[:3])
    if kind == "plate-mbc":
        t = PB @ (np.array(u_prev) / s["d"]) ** 2
        x_hat = [s["chain"][j].step(np.array([c[j], t[j] + _c(d, "g")])) for j in range(3)]
        e = [x_hat[j][0] - r[j][0] for j in range(3)]
        de = [x_hat[j][1] - r[j][1] for j in range(3)]
        v = np.array(
            [r[j][2] - _c(d, "c_d") * de[j] - _c(d, "c_p") * e[j] - _c(d, "g") - x_hat[j][2] for j in range(3)]
        )
        s["d"] = lam * (K @ c)
        u = s["d"] * np.sqrt(np.maximum(V @ v, 0.0))
        return list(u), [], [*(x_hat[j][2] + _c(d, "g") for j in range(3)), *e, *de]
    inp, gamma, a = int(_c(d, "input")), _c(d, "gamma"), d.law["weights"][0]
    z = [s["notch"][j].step(np.array([c[j]]))[0] for j in range(3)] if "notch" in s else list(c)
    i_prev = np.array(u_prev)
    if inp == 0:
        x_est = PB @ (i_prev / s["d"]) ** 2
    elif inp == 1:
        x_est = (i_prev[:3] / s["d"][:3]) ** 2
    elif inp == 2:
        x_est = (i_prev[:3] / s["h"][:3]) ** 2
    else:
        x_est = np.array(s["gy"]) * i_prev[:3]
    fed = [s["est"][j].step(z[j], float(x_est[j]), r[j]) for j in range(3)]
    wv = np.array([r[j][2] - _c(d, "k_p") * fed[j][1] - _c(d, "k_d") * fed[j][2] - fed[j][0] for j in range(3)])
    s["d"], s["h"] = lam * (K @ c), K @ c
    s["gy"] = [gamma / max(v, _c(d, "y_min")) for v in c]
    if inp == 0:
        u = s["d"] * np.sqrt(np.maximum(V @ (wv / gamma), 0.0))
    else:
        x3 = -wv / (np.array(s["gy"]) if inp == 3 else gamma)
        q = np.array([*x3, float(a @ x3)])
        u = q if inp == 3 else (s["d"] if inp == 1 else s["h"]) * np.sqrt(np.maximum(q, 0.0))
    est = [*(f[0] for f in fed), *(f[1] for f in fed), *(f[2] for f in fed)]
    return list(u), [], est


def _safety(d: Description, t: float, u, y, rates, inputs, outputs) -> dict[str, object] | None:
    """The first monitor that trips at this tick (docs/control-laws.md, "Safety routine")."""

    def label(monitor: str, names: list[str], j: int) -> str:
        return monitor if len(names) == 1 else f"{monitor}:{names[j]}"

    for monitor, values in (("non_finite_input", u), ("non_finite_output", y)):
        for v in values:
            if not math.isfinite(v):
                return {"status": "aborted", "monitor": monitor, "time": t, "value": v, "threshold": 0.0}
    checks = []
    if 1 in d.bounds:
        checks.append((y, outputs, *d.bounds[1], "output"))
    if 2 in d.bounds and d.derived is not None:
        derived = list(d.derived @ np.array(y))
        checks.append((derived, [f"h{j + 1}" for j in range(len(derived))], *d.bounds[2], "output"))
    if 0 in d.bounds:
        checks.append((u, inputs, *d.bounds[0], "input"))
    order = []  # low before high within each group: measured outputs, derived outputs, inputs
    for values, names, lo, hi, group in checks:
        order.append((f"{group}_low", values, names, lo, lambda v, b: v < b))
        order.append((f"{group}_high", values, names, hi, lambda v, b: v > b))
    for monitor, values, names, bounds, hit in order:
        for j, (v, b) in enumerate(zip(values, bounds)):
            if hit(v, b):
                return {"status": "aborted", "monitor": label(monitor, names, j), "time": t, "value": v, "threshold": b}
    if d.rate is not None:
        for j, rho in enumerate(rates):
            if rho >= d.rate[0]:
                return {"status": "aborted", "monitor": label("du_dt", inputs, j), "time": t, "value": rho,
                        "threshold": d.rate[0]}  # fmt: skip
    if t >= d.max_duration:
        return {"status": "aborted", "monitor": "run_time", "time": t, "value": t, "threshold": d.max_duration}
    return None
