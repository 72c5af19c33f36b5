"""A campaign's results in Python, as in a notebook (docs/python.md).

Run a campaign first, then point this at its directory:

    labrunner run campaigns/quickstart.toml      # → data/quickstart/
    python examples/results_in_python.py data/quickstart

``analyse`` need not have run: the table comes from the ledger. tests/test_results.py runs this
script on a small campaign.
"""

from __future__ import annotations

import sys

import labrunner


def main(directory: str) -> None:
    campaign = labrunner.open_campaign(directory)
    table = campaign.table()  # the columns of report/metrics.csv, one row per grid point
    print(f"{campaign.name}: {len(table)} points; parameters {campaign.parameters}")
    print(table["outcome"].value_counts().to_string())

    # the three completed runs that track best (aborted runs have no rms_error: it is in
    # rms_error_until_abort, so ranking never picks a run cut short)
    best = table.nsmallest(3, "rms_error")[["id", *campaign.parameters, "rms_error"]]
    print(best.to_string(index=False))

    # one run: its signals with time [s] and units, its configuration and outcome
    run = campaign.run(best["id"].iloc[0])
    signals = run.signals
    controlled = [name for name, role in run.roles.items() if role == "controlled"][0]
    print(f"run {run.id}: {len(signals)} samples at {run.fs:g} Hz, outcome {run.outcome['status']}")
    print(f"max |{controlled}| = {signals[controlled].abs().max():.4g} {run.units[controlled]}")
    print(f"controller: {run.config['controller']}")

    # selection by parameters: the last part of a dotted name will do when it is unique
    first_gain = campaign.parameters[-1]
    low = campaign.select({first_gain: slice(None, table[first_gain].median())})
    print(f"{len(low)} points with {first_gain} <= its median")

    # point × time (xarray): aborted runs padded with NaN, `valid` says which samples were logged
    chosen = campaign.select(outcome=["completed", "aborted"]).head(8)
    dataset = campaign.signals(chosen, names=[controlled])
    print(dataset[controlled].attrs["units"], dict(dataset.sizes), int(dataset["valid"].sum()), "samples logged")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python examples/results_in_python.py CAMPAIGN_DIR")
    main(sys.argv[1])
