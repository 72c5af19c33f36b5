"""The campaign pack: which files reproduce which figure or table, the source's claim, and the check.

Each :class:`Item` names its campaign files (relative to the project root), the claim of the thesis
or paper it reproduces, the check that measures it (a function of :mod:`labrunner.reproduce.checks`)
and, for ``--quick``, reduced ``[grid]`` sections that replace the files' own (a grid axis with a
single value also shortens a reference, e.g. ``"reference.hold" = { values = [1.5] }``). An item
without a quick grid for some file runs that file in full in ``--quick``; ``quick=False`` leaves the
item out of ``--quick`` altogether (the report says so).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

T = "campaigns/thesis/"
V = "campaigns/valve-paper/"
P = "campaigns/plate-paper/"
TABLE3 = ("horizontal", "tilt", "actuator-offset", "actuator-gain", "sensor")
_VALVE_SHORT = '\n"reference.transition" = { values = [1.5] }\n"reference.hold" = { values = [1.5] }'


@dataclass(frozen=True)
class Item:
    """One figure or table of the sources and how the pack reproduces it."""

    id: str  # what --only selects, e.g. "3.10", "valve-7", "table3"
    title: str
    source: str  # "thesis", "paper 1", "paper 2"
    files: tuple[str, ...]
    claim: str
    check: str  # name of the check function in labrunner.reproduce.checks
    quick_grids: Mapping[str, str] = field(default_factory=dict)  # file → [grid] body for --quick
    quick: bool = True


ITEMS: tuple[Item, ...] = (
    Item(
        "ident",
        "Identification of a and b (Sec. 3.2)",
        "thesis",
        ("campaigns/dcmotor-identification.toml",),
        "The four steps (±6, ±12 V, 100 Hz), α = β = 6, ω_c = 50 rad/s, give a = 39.44 1/s, b = 108.55 rad/(V s²).",
        "identification",
    ),
    Item(
        "3.7",
        "Angle MFC, α–ω_c at f_s = 20 Hz (Fig. 3.7)",
        "thesis",
        (T + "fig3-07-angle-fs20.toml",),
        "No combination of α = β ∈ {2..9}, ω_c = 25 rad/s is unstable.",
        "unstable_differentiators",
    ),
    Item(
        "3.8",
        "Angle MFC, α–ω_c at f_s = 200 Hz (Fig. 3.8, Table 3.2 a)",
        "thesis",
        (T + "fig3-08-angle-fs200.toml",),
        "Four combinations are unstable (aborted): α = 2 at three of the highest cutoffs, α = 3 at one.",
        "unstable_differentiators",
        {
            T + "fig3-08-angle-fs200.toml": '"differentiator.omega_c" = { values = [100.0, 150.0, 200.0] }\n'
            '"differentiator.alpha" = { values = [2, 3, 5, 9] }'
        },
    ),
    Item(
        "3.9",
        "Angle MFC, α–ω_c at f_s = 1 kHz (Fig. 3.9, Table 3.2 b)",
        "thesis",
        (T + "fig3-09-angle-fs1000.toml",),
        "Five combinations are unstable: α = 2 at three of the highest cutoffs, α = 3 at two.",
        "unstable_differentiators",
        {
            T + "fig3-09-angle-fs1000.toml": '"differentiator.omega_c" = { values = [100.0, 150.0, 200.0] }\n'
            '"differentiator.alpha" = { values = [2, 3, 5, 9] }'
        },
    ),
    Item(
        "3.10",
        "Velocity MFC, γ_Ω–k_p (Fig. 3.10)",
        "thesis",
        ("campaigns/dcmotor-velocity-gamma-kp.toml",),
        "The bound (2.46) with the model (2.31) explains the map; along a line of constant γ_Ω/k_p the loops "
        "behave alike (Sec. 3.5.1).",
        "gamma_kp_map",
        {
            "campaigns/dcmotor-velocity-gamma-kp.toml": '"controller.gamma" = { log10 = [0.0, 4.0], num = 9 }\n'
            '"controller.k_p" = { log10 = [-1.0, 3.0], num = 9 }'
        },
    ),
    Item(
        "3.11",
        "Constant-ratio lines (Figs. 3.11, 3.12)",
        "thesis",
        (T + "fig3-11-constant-ratio.toml",),
        "Runs on one line of constant γ_Ω/k_p behave alike; the line nearest the edge is best, larger ratios "
        "degrade the tracking.",
        "constant_ratio_lines",
    ),
    Item(
        "3.14",
        "Angle MFC, k_p–k_d, γ_θ = b (Fig. 3.14)",
        "thesis",
        ("campaigns/dcmotor-angle-kp-kd.toml",),
        "The bounds (2.58)–(2.59) describe the stable set; the ultra-local bounds (2.53)–(2.54) are conservative.",
        "bound_agreement",
        {
            "campaigns/dcmotor-angle-kp-kd.toml": '"controller.k_p" = { log10 = [0.0, 4.0], num = 9 }\n'
            '"controller.k_d" = { log10 = [0.0, 2.5], num = 6 }'
        },
    ),
    Item(
        "3.15",
        "Angle MFC, the white rectangle sampled finely (Fig. 3.15, 3.20)",
        "thesis",
        (T + "fig3-15-angle-kp-kd-fine.toml",),
        "The bounds (2.58)–(2.59) are accurate here, although a region inside them is aborted by the safety "
        "routine; the smallest RMS of e_θ lies at log10 k_p = 3.1875, log10 k_d = 1.9375.",
        "fine_kp_kd",
        {
            T + "fig3-15-angle-kp-kd-fine.toml": '"controller.k_p" = { log10 = [2.5, 3.5], num = 9 }\n'
            '"controller.k_d" = { log10 = [1.5, 2.25], num = 7 }'
        },
    ),
    Item(
        "3.17",
        "Angle MFC, k_p–k_d, γ_θ = 1.1 b (Fig. 3.17)",
        "thesis",
        (T + "fig3-17-angle-kp-kd-gamma-1.1b.toml",),
        "With γ_θ = 1.1 b the bound allows k_d,min = −3.54 1/s; the experiments differ from it in some regions.",
        "bound_agreement",
        {
            T + "fig3-17-angle-kp-kd-gamma-1.1b.toml": '"controller.k_p" = { log10 = [0.0, 4.0], num = 9 }\n'
            '"controller.k_d" = { log10 = [0.0, 2.5], num = 6 }'
        },
    ),
    Item(
        "3.19",
        "Angle MFC, k_p–k_d, γ_θ = 0.9 b (Fig. 3.19)",
        "thesis",
        (T + "fig3-19-angle-kp-kd-gamma-0.9b.toml",),
        "With γ_θ = 0.9 b the bound gives k_d,min = 4.33 1/s; points below it are predicted unstable but run stably.",
        "bound_conservative",
        {
            T + "fig3-19-angle-kp-kd-gamma-0.9b.toml": '"controller.k_p" = { log10 = [0.0, 4.0], num = 9 }\n'
            '"controller.k_d" = { log10 = [0.0, 2.5], num = 6 }'
        },
    ),
    Item(
        "3.21-3.23",
        "Polack et al. vs Guideline 2 (Figs. 3.21, 3.23, Sec. 3.5.3)",
        "thesis",
        (T + "fig3-21a-polack-feedforward.toml", T + "fig3-21c-polack-feedback.toml", T + "fig3-23-guideline2.toml"),
        "Polack's feed-forward stage aborts below γ_Ω = 64.93 and picks 74.98 (66 steps), its feedback stage "
        "k_p = 31.62 (41 steps): 107 steps; Guideline 2 reaches the same RMS (0.29 rad/s) at γ_Ω = 421.69, "
        "k_p = 237.13 after 54 steps.",
        "tuning_walks",
    ),
    Item(
        "valve-7",
        "Six differentiators, γ–k_p (paper 1 Fig. 7)",
        "paper 1",
        (V + "fig07-parametrisations.toml",),
        "All six parametrisations of Table 1 give a stability region of the same shape in about the same place.",
        "valve_parametrisations",
        {
            V + "fig07-parametrisations.toml": 'zip = [["differentiator.alpha", "differentiator.omega_c"]]\n'
            '"differentiator.alpha" = { values = [2, 2, 4, 3, 2, 8] }\n'
            '"differentiator.omega_c" = { values = [250.0, 450.0, 850.0, 450.0, 150.0, 250.0] }\n'
            '"controller.gamma" = { log10 = [-2.0, 1.0], num = 3 }\n'
            '"controller.k_p" = { log10 = [0.0, 3.0], num = 3 }' + _VALVE_SHORT
        },
    ),
    Item(
        "valve-8",
        "Constant-ratio lines (paper 1 Figs. 5, 8)",
        "paper 1",
        (V + "fig08-constant-ratio.toml",),
        "Parameter pairs on one line of constant γ/k_p give similar closed loops even a decade apart.",
        "constant_ratio_lines",
    ),
    Item(
        "valve-9-10",
        "MFC vs feed-forward control (paper 1 Figs. 9, 10)",
        "paper 1",
        (V + "fig09-10-mfc.toml", V + "fig09-10-ffc.toml"),
        "The MFC's RMS of e_q is below the FFC's for every end value of the commanded flow (4–14 l/min).",
        "mfc_vs_ffc",
        {
            V
            + "fig09-10-mfc.toml": '"reference.levels" = { values = [[2.0, 4.0, 2.0], [2.0, 10.0, 2.0], [2.0, 14.0, 2.0]] }',
            V
            + "fig09-10-ffc.toml": '"reference.levels" = { values = [[2.0, 4.0, 2.0], [2.0, 10.0, 2.0], [2.0, 14.0, 2.0]] }',
        },
    ),
    Item(
        "plate-4",
        "Differentiators of the plate MFC, α–ω_c (paper 2 Fig. 4)",
        "paper 2",
        ("campaigns/plate-alpha-omegac.toml",),
        "The RMS of ê_1..3 is lowest near α = β = 4, ω_c = 840 rad/s (the paper's choice).",
        "plate_optimum",
        quick=False,
    ),
    Item(
        "plate-7",
        "Plate MFC, k_p–k_d (paper 2 Fig. 7)",
        "paper 2",
        (P + "fig07-kp-kd.toml",),
        "k_p = 5000 1/s², k_d = 195 1/s lie near the minimum of all three RMS values.",
        "plate_optimum",
        quick=False,
    ),
    Item(
        "plate-8",
        "Input gains of the four MFC laws (paper 2 Fig. 8)",
        "paper 2",
        (P + "fig08-input-gains.toml",),
        "γ_v = 0.6 gives the lowest RMS, 0.5 is unstable; γ_F = 0.84 is unstable on the test bed; "
        "γ_u = 1.4·10⁻⁵ beats 1.6·10⁻⁵.",
        "plate_input_gains",
        quick=False,
    ),
    Item(
        "table3",
        "MBC vs the four MFC input laws under movements and faults (paper 2 Table 3)",
        "paper 2",
        tuple(P + f"table3-{e}-{k}.toml" for e in TABLE3 for k in ("mbc", "mfc")),
        "MFC v beats the MBC in every experiment but the sensor fault (about half its RMS); using less model "
        "information (F̄, u, then i) raises the RMS; the MFC of the current is about five times worse.",
        "table3",
    ),
)

#: Table 3 experiments left out of --quick (the longest runs; the rest keep the ordering checks meaningful).
QUICK_SKIP = tuple(P + f"table3-{e}-{k}.toml" for e in ("tilt", "actuator-gain") for k in ("mbc", "mfc"))


def select(only: tuple[str, ...] | None) -> tuple[Item, ...]:
    """The items ``--only`` names (all when None); an unknown id is an error naming the known ones."""
    from labrunner.errors import InvalidParameter

    if not only:
        return ITEMS
    known = {item.id: item for item in ITEMS}
    unknown = [o for o in only if o not in known]
    if unknown:
        raise InvalidParameter("--only", f"unknown figure {unknown[0]!r}; known: {', '.join(known)}")
    return tuple(known[o] for o in dict.fromkeys(only))
