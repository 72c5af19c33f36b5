"""``labrunner differentiator``: design an algebraic differentiator and print its FIR weights."""

from __future__ import annotations

import argparse

from labrunner.cli.argtypes import numeric


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "differentiator",
        help="design an algebraic differentiator (window, delay, cutoff, FIR weights, cost J_n)",
        description=(
            "Design an algebraic differentiator (thesis Sec. 2.1) from alpha, beta, N, theta and "
            "either the cutoff --omega-c [rad/s] or the window --window [s] at sampling rate --fs [Hz]; "
            "print its realised window, delays, cutoff and normalised FIR weights (newest sample first)."
        ),
    )
    p.add_argument(
        "--alpha", type=numeric(float, "> -1"), required=True, help="weight exponent alpha in (-1, 200] (alpha > n - 1)"
    )
    p.add_argument(
        "--beta", type=numeric(float, "> -1"), required=True, help="weight exponent beta in (-1, 200] (beta > n - 1)"
    )
    p.add_argument(
        "--N",
        type=numeric(int, ">= 0"),
        default=0,
        help="truncation order N in 0..20 of the Jacobi expansion (default 0)",
    )
    p.add_argument(
        "--theta",
        type=numeric(float, "in [-1, 1]"),
        help="theta in [-1, 1] for N > 0 (default: largest root of P_{N+1})",
    )
    p.add_argument("--omega-c", type=numeric(float, "> 0"), dest="omega_c", help="desired cutoff frequency [rad/s]")
    p.add_argument("--window", type=numeric(float, "> 0"), help="filter window length T [s]")
    p.add_argument("--fs", type=numeric(float, "> 0"), required=True, help="sampling frequency [Hz]")
    p.add_argument(
        "--order", type=numeric(int, ">= 0"), default=1, help="derivative order n of the weights (default 1)"
    )
    p.add_argument(
        "--method",
        choices=("midpoint", "trapezoidal", "analytic"),
        default="midpoint",
        help="discretisation of the convolution integral (default midpoint)",
    )
    p.add_argument(
        "--cost",
        action="store_true",
        help="also compute the discretisation cost J_n [dB] up to Nyquist (windows up to 10 000 taps)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a summary")
    p.set_defaults(func=run)


def describe(args: argparse.Namespace) -> dict:
    """The JSON object of the command: design, delays, weights and (with --cost) cost_db."""
    from labrunner.differentiators import design
    from labrunner.differentiators.spectra import cost_db

    d = design(
        alpha=args.alpha,
        beta=args.beta,
        fs=args.fs,
        omega_c=args.omega_c,
        window=args.window,
        N=args.N,
        theta=args.theta,
        method=args.method,
    )
    w = d.weights(args.order)
    out = {
        "alpha": d.alpha,
        "beta": d.beta,
        "N": d.N,
        "theta": d.theta,
        "fs": d.fs,
        "n_s": d.n_s,
        "window_s": d.window_s,
        "delay_s": d.delay_s,
        "discrete_delay_s": d.discrete_delay_s(args.order),
        "omega_c_actual": d.omega_c_actual,
        "order": args.order,
        "method": d.method,
        "weights": w.tolist(),
    }
    if args.cost:
        out["cost_db"] = cost_db(d, args.order)
    return out


def _summary(info: dict) -> str:
    lines = [
        f"algebraic differentiator  alpha = {info['alpha']:g}, beta = {info['beta']:g}, N = {info['N']}"
        + (f", theta = {info['theta']:.6g}" if info["N"] else "")
        + f", {info['method']}, fs = {info['fs']:g} Hz",
        f"  window   T = {info['window_s']:.6g} s  (n_s = {info['n_s']} samples)",
        f"  cutoff   omega_c = {info['omega_c_actual']:.6g} rad/s (of the realised window)",
        f"  delay    {info['delay_s'] * 1e3:.6g} ms continuous, {info['discrete_delay_s'] * 1e3:.6g} ms discrete",
    ]
    if "cost_db" in info:
        lines.append(f"  cost     J_{info['order']} = {info['cost_db']:.1f} dB (up to Nyquist)")
    w = info["weights"]
    lines.append(f"  weights  order {info['order']}, {len(w)} taps, newest sample first:")
    lines.extend(f"    {j:5d}  {v: .17g}" for j, v in enumerate(w))
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    import json

    info = describe(args)
    print(json.dumps(info) if args.json else _summary(info))
    return 0
