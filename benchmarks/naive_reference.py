"""The per-sample script a researcher would write for a motor γ–k_p campaign: the yardstick of
benchmarks/bench_campaign.py (issue 14), compute only, nothing logged.

For every grid point, one closed loop at a time and one sample at a time, in one of two styles:
``--style numpy`` (default) is the script most researchers write, numpy arrays and matrix-vector
products per sample (``np.roll`` histories, ``w @ window``, ``Φ @ z``); ``--style floats`` is a
tuned per-sample script in plain Python floats and lists, ~5× faster, the stricter yardstick.
Both compute
the simulated DC motor of ``rigs/dcmotor-sim.toml`` (exact ZOH sub-steps, Coulomb and static
friction, backlash, electrical lag, voltage noise, encoder; labrunner/rigs/sim/dcmotor.py), the
velocity Ω from the encoder by the difference quotient (thesis (2.34)), the first-order MFC
(thesis (2.35), (3.3)–(3.4)) with the campaign's algebraic differentiator, input saturation, and
the safety routine |u̇| ≥ max_du_dt (thesis Sec. 3.3) that ends a run. Differentiator weights come
from labrunner's design (``labrunner.differentiators.design``), the ZOH matrices from
``scipy.linalg.expm``; everything per sample is written out here. tests/test_naive_reference.py
checks that both styles' loops are the engine's.

    python benchmarks/naive_reference.py [CAMPAIGN.toml] [--style numpy|floats] [--gamma-num 40 --kp-num 25]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
from scipy.linalg import expm

from labrunner.differentiators import design

ROOT = Path(__file__).resolve().parents[1]


class Motor:
    """The motor twin for one run, one sample at a time (labrunner/rigs/sim/dcmotor.py's model)."""

    def __init__(self, p: dict, fs: float, seed: int) -> None:
        self.p = p
        self.n_sub = max(1, int(np.ceil((1.0 / fs) / p["max_substep"] - 1e-9)))
        h = 1.0 / (fs * self.n_sub)
        a, b, tau = p["a"], p["b"], p["electrical_tau"]
        lag = tau > 0.0
        # ẋ = A x + B w, x = (θ_m, Ω, v), w = (commanded voltage, friction voltage); Van Loan's expm
        M = np.zeros((5, 5))
        M[0, 1] = 1.0
        M[1, 1], M[1, 2] = -a, (b if lag else 0.0)
        M[2, 2] = -1.0 / tau if lag else 0.0
        M[1, 3], M[1, 4], M[2, 3] = (0.0 if lag else b), -b, (1.0 / tau if lag else 0.0)
        self.M = expm(M * h)[:3].tolist()  # rows of [Φ | Γ]
        self.lag = lag
        self.z = [0.0] * 5  # θ_m, Ω, v, v_cmd, F
        self.theta = 0.0  # the load behind the backlash
        self.d = 2.0 * math.pi / p["encoder_counts"]
        self.rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([seed, 1])))

    def measure(self) -> float:
        return round(self.theta / self.d) * self.d

    def step(self, u: float) -> float:
        """Hold ``u`` [V] over one sample; return the encoder reading [rad]."""
        p, z, M = self.p, self.z, self.M
        v = min(max(u, -p["u_max"]), p["u_max"])  # the rig's input limits
        if p["input_v"] > 0.0:
            v = v + p["input_v"] * self.rng.standard_normal()
        z[3] = min(max(v, -p["u_max"]), p["u_max"])  # the driver's saturation
        us, uc, half = p["static_friction"], p["coulomb_friction"], 0.5 * p["backlash"]
        for _ in range(self.n_sub):
            stuck = z[1] == 0.0
            drive = M[2][2] * z[2] + M[2][3] * z[3] if self.lag else z[3]  # voltage at the sub-step's end
            s = float(np.sign(z[1] + drive)) if stuck else float(np.sign(z[1]))
            hold = stuck and us > 0.0 and abs(drive) <= us  # static friction holds the load
            z[4] = uc * s
            xn = []
            for row in M:
                acc = row[0] * z[0]
                for j in range(1, 5):
                    acc = acc + row[j] * z[j]
                xn.append(acc)
            if hold:
                xn[0] = z[0]
            if hold or (xn[1] * s < 0.0 and uc > 0.0):  # Coulomb friction stops a reversal
                xn[1] = 0.0
            z[:3] = xn
            self.theta = min(max(self.theta, z[0] - half), z[0] + half)
        return self.measure()


def setpoints(levels: list[float], transition: float, hold: float, t: float) -> tuple[float, float]:
    """Reference and its derivative: levels joined by poly-5 transitions (10τ³ − 15τ⁴ + 6τ⁵)."""
    r, dr, start = levels[0], 0.0, hold
    for lo, hi in zip(levels, levels[1:]):
        x = (t - start) / transition
        tau = min(max(x, 0.0), 1.0)
        r += (hi - lo) * tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
        dr += (hi - lo) / transition * 30.0 * tau**2 * (1.0 - tau) ** 2
        start += transition + hold
    return r, dr


def closed_loop(gamma: float, k_p: float, cfg: dict) -> dict:
    """One run of the first-order velocity MFC on the motor; returns θ, Ω, u per sample and the end."""
    fs = cfg["fs"]
    K = int(round(cfg["duration"] * fs))
    w0, w1, w_rate = cfg["w0"], cfg["w1"], cfg["w_rate"]
    ref = cfg["reference"]
    motor = Motor(cfg["plant"], fs, cfg["seed"])
    u_lo, u_hi = -cfg["plant"]["u_max"], cfg["plant"]["u_max"]
    theta_prev = motor.measure()
    y = theta_prev
    om_hist = [0.0] * (len(w1) + 1)  # Ω[k], Ω[k−1], …: a stationary past
    e_hist = [0.0] * len(w0)  # e = Ω − Ω_r, zero initial error
    v_hist = [0.0] * len(w0)  # applied u[k−1], u[k−2], …
    u_hist = [0.0] * len(w_rate)  # commanded u for the safety routine
    out = {"theta": [], "omega": [], "u": [], "end": K, "aborted": False}
    for k in range(K):
        r, dr = setpoints(ref["levels"], ref["transition"], ref["hold"], k / fs)
        omega = (y - theta_prev) * fs  # (2.34)
        theta_prev = y
        om_hist = [omega] + om_hist[:-1]
        e_hist = [omega - r] + e_hist[:-1]
        f_hat = sum(w * x for w, x in zip(w1, om_hist[1:])) - gamma * sum(w * x for w, x in zip(w0, v_hist))
        e_hat = sum(w * x for w, x in zip(w0, e_hist))
        u = min(max((dr - f_hat) * (1.0 / gamma) - k_p / gamma * e_hat, u_lo), u_hi)  # (2.35), saturated
        v_hist = [u] + v_hist[:-1]
        u_hist = [u] + u_hist[:-1]
        out["theta"].append(y)
        out["omega"].append(omega)
        out["u"].append(u)
        if abs(sum(w * x for w, x in zip(w_rate, u_hist))) >= cfg["max_du_dt"]:  # safety routine
            out["end"], out["aborted"] = k + 1, True
            break
        y = motor.step(u)
    return out


class NumpyMotor(Motor):
    """The same motor with its state in a numpy array and one ``Φ @ z`` per sub-step."""

    def __init__(self, p: dict, fs: float, seed: int) -> None:
        super().__init__(p, fs, seed)
        self.M = np.array(self.M)
        self.z = np.zeros(5)

    def step(self, u: float) -> float:
        p, z, M = self.p, self.z, self.M
        v = np.clip(u, -p["u_max"], p["u_max"])
        if p["input_v"] > 0.0:
            v = v + p["input_v"] * self.rng.standard_normal()
        z[3] = np.clip(v, -p["u_max"], p["u_max"])
        us, uc, half = p["static_friction"], p["coulomb_friction"], 0.5 * p["backlash"]
        for _ in range(self.n_sub):
            stuck = z[1] == 0.0
            drive = M[2, 2] * z[2] + M[2, 3] * z[3] if self.lag else z[3]
            s = np.sign(z[1] + drive) if stuck else np.sign(z[1])
            hold = stuck and us > 0.0 and abs(drive) <= us
            z[4] = uc * s
            xn = M @ z
            if hold:
                xn[0] = z[0]
            if hold or (xn[1] * s < 0.0 and uc > 0.0):
                xn[1] = 0.0
            z[:3] = xn
            self.theta = np.clip(self.theta, z[0] - half, z[0] + half)
        return self.measure()


def push(window: np.ndarray, x: float) -> np.ndarray:
    """The window shifted by one sample with ``x`` as its newest entry."""
    window = np.roll(window, 1)
    window[0] = x
    return window


def closed_loop_numpy(gamma: float, k_p: float, cfg: dict) -> dict:
    """:func:`closed_loop` as most researchers write it: numpy windows and dot products per sample."""
    fs = cfg["fs"]
    K = int(round(cfg["duration"] * fs))
    w0, w1, w_rate = (np.array(cfg[key]) for key in ("w0", "w1", "w_rate"))
    ref = cfg["reference"]
    motor = NumpyMotor(cfg["plant"], fs, cfg["seed"])
    u_max = cfg["plant"]["u_max"]
    theta_prev = motor.measure()
    y = theta_prev
    om_hist, e_hist, v_hist, u_hist = np.zeros(len(w1) + 1), np.zeros(len(w0)), np.zeros(len(w0)), np.zeros(len(w_rate))
    theta, omega_log, u_log = np.zeros(K), np.zeros(K), np.zeros(K)
    end, aborted = K, False
    for k in range(K):
        r, dr = setpoints(ref["levels"], ref["transition"], ref["hold"], k / fs)
        omega = (y - theta_prev) * fs  # (2.34)
        theta_prev = y
        om_hist = push(om_hist, omega)
        e_hist = push(e_hist, omega - r)
        f_hat = w1 @ om_hist[1:] - gamma * (w0 @ v_hist)
        u = np.clip((dr - f_hat) / gamma - k_p / gamma * (w0 @ e_hist), -u_max, u_max)  # (2.35), saturated
        v_hist = push(v_hist, u)
        u_hist = push(u_hist, u)
        theta[k], omega_log[k], u_log[k] = y, omega, u
        if abs(w_rate @ u_hist) >= cfg["max_du_dt"]:  # safety routine
            end, aborted = k + 1, True
            break
        y = motor.step(u)
    return {"theta": theta[:end], "omega": omega_log[:end], "u": u_log[:end], "end": end, "aborted": aborted}


STYLES = {"numpy": closed_loop_numpy, "floats": closed_loop}


def load(campaign: Path) -> tuple[dict, np.ndarray, np.ndarray]:
    """The closed loop's settings and the γ, k_p grid axes from a motor γ–k_p campaign file."""
    c = tomllib.loads(campaign.read_text())
    rig = tomllib.loads((ROOT / "rigs" / f"{c['campaign']['rig']}.toml").read_text())
    plant = {**rig["parameters"], **rig["noise"], "max_substep": 1.25e-3}
    fs = float(c["campaign"]["fs"])
    dc = c["differentiator"]
    d = design(alpha=dc["alpha"], beta=dc["beta"], N=dc.get("N", 0), omega_c=dc["omega_c"], fs=fs, method=dc["method"])
    safety = {**rig["safety"], **c.get("safety", {})}
    rate = design(alpha=safety["du_dt_alpha"], beta=safety["du_dt_beta"], omega_c=safety["du_dt_omega_c"], fs=fs)
    ref = c["reference"]
    cfg = {
        "fs": fs,
        "duration": float(c["campaign"]["duration"]),
        "seed": int(c["campaign"]["seed"]),
        "plant": plant,
        "w0": d.weights(0).tolist(),
        "w1": d.weights(1).tolist(),
        "w_rate": rate.weights(1).tolist(),
        "max_du_dt": float(safety["max_du_dt"]),
        "reference": {"levels": ref["levels"], "transition": float(ref["transition"]), "hold": float(ref["hold"])},
    }
    axes = [np.logspace(*g["log10"], g["num"]) for g in (c["grid"]["controller.gamma"], c["grid"]["controller.k_p"])]
    return cfg, axes[0], axes[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("campaign", nargs="?", default=str(ROOT / "campaigns" / "quickstart.toml"))
    parser.add_argument("--style", choices=sorted(STYLES), default="numpy", help="the script's style (default numpy)")
    parser.add_argument("--gamma-num", type=int, help="γ grid points (default: the campaign's)")
    parser.add_argument("--kp-num", type=int, help="k_p grid points (default: the campaign's)")
    args = parser.parse_args()
    cfg, gammas, kps = load(Path(args.campaign))
    if args.gamma_num:
        gammas = np.logspace(math.log10(gammas[0]), math.log10(gammas[-1]), args.gamma_num)
    if args.kp_num:
        kps = np.logspace(math.log10(kps[0]), math.log10(kps[-1]), args.kp_num)
    t0, c0 = time.perf_counter(), time.process_time()
    aborted = samples = 0
    for gamma in gammas:
        for k_p in kps:
            run = STYLES[args.style](float(gamma), float(k_p), cfg)
            aborted += run["aborted"]
            samples += run["end"]
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    n = len(gammas) * len(kps)
    print(
        f"naive reference ({args.style}): {n} runs ({aborted} aborted, {samples} samples) in {wall:.2f} s wall, {cpu:.2f} s CPU"
    )
    sys.stdout.flush()


if __name__ == "__main__":
    main()
