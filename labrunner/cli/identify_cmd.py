"""``labrunner identify LOGS... [--friction] [--json]``: a and b of θ̈ = −aθ̇ + bu from step experiments
(thesis 3.2), and with ``--friction`` a pooled fit of θ̈ = −aθ̇ + b(u − u_c sign θ̇)."""

from __future__ import annotations

import argparse
import json

from labrunner.cli.argtypes import path_text


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "identify",
        help="identify the DC motor's a and b from open-loop run logs",
        description=(
            "Least-squares identification of a [1/s] and b [rad/(V s²)] of θ̈ = −a θ̇ + b u per run log, "
            "with θ̇, θ̈ and the filtered u from algebraic differentiators (N = 0, α = β = 6, ω_c = 50 rad/s, "
            "mid-point), then the mean over the logs (thesis Sec. 3.2). A campaign directory stands for its "
            "runs/*.mcap."
        ),
    )
    p.add_argument("logs", nargs="+", type=path_text, metavar="LOG", help="run logs (.mcap) or campaign directories")
    p.add_argument("--input", metavar="NAME", help="input channel (default: the rig's first input)")
    p.add_argument("--output", metavar="NAME", help="angle channel (default: the first measurement named theta*)")
    p.add_argument(
        "--friction",
        action="store_true",
        help="also fit a Coulomb voltage u_c [V]: θ̈ = −a θ̇ + b (u − u_c sign θ̇), pooled over the logs "
        "(needs steps of at least two heights)",
    )
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from labrunner.errors import InvalidParameter
    from labrunner.identification import identify_logs, nominal_constants, physical_parameters

    paths: list[Path] = []
    for item in map(Path, args.logs):
        if item.is_dir():
            paths += sorted((item / "runs").glob("*.mcap")) or sorted(item.glob("*.mcap"))
        elif item.is_file():
            paths.append(item)
        else:
            raise InvalidParameter("LOGS", f"{str(item)!r} does not exist")
    if not paths:
        raise InvalidParameter("LOGS", "no run logs (.mcap) found")
    result = identify_logs(
        paths,
        input_name=args.input,
        output_name=args.output,
        nominal=nominal_constants(paths[0]),
        friction=args.friction,
    )
    physical = physical_parameters(paths[0]) if args.friction else None
    if physical:
        result["physical"] = physical
    if args.json:
        print(json.dumps(result, ensure_ascii=False))
        return 0
    for r in result["per_run"]:
        print(
            f"{r['log']}: a = {r['a']:.4g} 1/s, b = {r['b']:.4g} rad/(V s²) (u = {r['u_final']:+g} V, {r['n_samples']} samples)"
        )
    print(f"mean over {len(result['per_run'])} runs: a = {result['a']:.4g} 1/s, b = {result['b']:.4g} rad/(V s²)")
    if "bias" in result:
        nominal, bias = result["nominal"], result["bias"]
        print(
            "rig's nominal values: " + ", ".join(f"{k} = {v:.4g} (estimate {bias[k]:+.1%})" for k, v in nominal.items())
        )
    if args.friction:
        f = result["friction"]
        print(
            f"with Coulomb friction, pooled over {len(result['per_run'])} runs: a = {f['a']:.4g} 1/s, "
            f"b = {f['b']:.4g} rad/(V s²), u_c = {f['coulomb']:.3g} V"
        )
        if physical:
            print(
                "twin's physical values: "
                + ", ".join(
                    f"{k} = {v:.4g} (estimate {f[k] / v - 1:+.1%})" if v else f"{k} = 0 (estimate {f[k]:.3g})"
                    for k, v in physical.items()
                )
            )
    return 0
