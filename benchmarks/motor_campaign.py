"""The motor campaign the start-up and analysis benchmarks time: first-order MFC of the simulated
DC motor's velocity with the thesis's nominal γ = b, k_p and differentiator (Sec. 3.4), as TOML."""

from __future__ import annotations


def motor_campaign(
    name: str, *, levels: str, hold: float, duration: float | None = None, description: str = "", grid: str = ""
) -> str:
    """A campaign file: set points ``levels`` (TOML list) held ``hold`` s, optional ``duration``
    [s], ``description`` and ``[grid]`` body ``grid``."""
    head = f'name = "{name}"\n' + (f'description = "{description}"\n' if description else "")
    head += 'rig = "dcmotor-sim"\nfs = 200.0\n' + (f"duration = {duration}\n" if duration is not None else "")
    body = (
        '[controller]\nkind = "mfc1"\noutput = "velocity"\ngamma = 108.55\nk_p = 50.0\n\n'
        "[differentiator]\nalpha = 9\nbeta = 9\nomega_c = 200.0\n\n"
        f'[reference]\nkind = "setpoints"\nlevels = {levels}\ntransition = 1.0\nhold = {hold}\n'
    )
    return f"[campaign]\n{head}\n{body}" + (f"\n[grid]\n{grid}" if grid else "")
