"""``labrunner bounds``: stability intervals of the MFC gains for a delay (thesis section 2.4,
appendix A, corrected), optionally checked by the numerical spectral-abscissa solver."""

from __future__ import annotations

import argparse
import math

from labrunner.cli.argtypes import numeric

CASE_NAMES = ("mfc1-ultralocal", "mfc1-motor", "mfc2-ultralocal", "mfc2-motor", "mfc2-second-order")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "bounds",
        help="stability intervals of k_p (and k_d) for an estimation delay",
        description=(
            "Closed-form stability intervals (open) of the MFC gains for an estimation delay, "
            "from thesis section 2.4 and appendix A with its errors corrected; --numeric adds the "
            "intervals found by the spectral-abscissa solver. Second-order cases give the k_d "
            "interval and the k_p interval at --k-d."
        ),
    )
    p.add_argument("--case", required=True, choices=CASE_NAMES)
    p.add_argument("--gamma", required=True, type=numeric(float, "> 0"), help="input gain γ of the MFC law (> 0)")
    p.add_argument("--delay", required=True, type=numeric(float, "> 0"), help="estimation delay δ [s] (> 0)")
    p.add_argument("--rho", type=numeric(float, "> 0"), help="ultra-local input gain ρ (> 0; default --b)")
    p.add_argument(
        "--a", type=numeric(float, "(any real)"), help="plant coefficient a [1/s] (motor cases; < 0: unstable plant)"
    )
    p.add_argument("--b", type=numeric(float, "> 0"), help="plant input gain b (> 0)")
    p.add_argument("--a0", type=numeric(float, ">= 0"), help="a₀ [1/s²] of the second-order plant (A.15), >= 0")
    p.add_argument("--a1", type=numeric(float, "(any real)"), help="a₁ [1/s] of the second-order plant (A.15)")
    p.add_argument(
        "--k-d", dest="k_d", type=numeric(float, "(any real)"), help="derivative gain k_d [1/s] (second-order cases)"
    )
    p.add_argument("--numeric", action="store_true", help="also compute the intervals numerically")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def _end(value: float, lo: float, hi: float) -> str:
    """One end of an interval; the numerical solver's round-off around a bound of 0 (±1e-15) is
    printed as 0, since |value| ≤ 1e-9 of the interval's larger end is no information."""
    scale = max(abs(lo), abs(hi)) if all(map(math.isfinite, (lo, hi))) else 1.0
    return "0" if abs(value) <= 1e-9 * scale else f"{value:.10g}"


def _fmt(interval) -> str:
    if interval is None:
        return ": none stable"
    pairs = interval if isinstance(interval[0], list) else [interval]
    return " in " + " or ".join(f"({_end(lo, lo, hi)}, {_end(hi, lo, hi)})" for lo, hi in pairs)


def _lines(result: dict, k_d: float | None) -> list[str]:
    out = []
    if "k_d" in result:
        out.append(f"k_d{_fmt(result['k_d'])}")
        out.append(f"k_p{_fmt(result['k_p'])} at k_d = {k_d:g}")
    else:
        out.append(f"k_p{_fmt(result['k_p'])}")
    return out


def run(args: argparse.Namespace) -> int:
    import json

    from labrunner.stability import bounds

    result = bounds(
        args.case,
        gamma=args.gamma,
        delay=args.delay,
        rho=args.rho,
        a=args.a,
        b=args.b,
        k_d=args.k_d,
        a0=args.a0,
        a1=args.a1,
        numeric=args.numeric,
    )
    if args.json:
        print(json.dumps(result))
        return 0
    print(f"{args.case}: gamma = {args.gamma:g}, delay = {args.delay:g} s")
    print("\n".join("  " + line for line in _lines(result, args.k_d)))
    if "numeric" in result:
        print("  numerical solver:")
        print("\n".join("    " + line for line in _lines(result["numeric"], args.k_d)))
    return 0
