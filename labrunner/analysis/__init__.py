"""Campaign analysis: per-run metrics, maps with the thesis's markers and stability overlays, run
plots and a self-contained HTML report (``labrunner analyse``).

Modules: :mod:`.table` (ledger + MCAPs → cached table of :mod:`labrunner.metrics`),
:mod:`.maps` (heat maps, sweeps, markers), :mod:`.overlays` (which stability bounds go on which map), :mod:`.agreement` (outcomes vs. predicted stability),
:mod:`.figures` (the campaign's figures), :mod:`.report` (index.html), :mod:`.analyse` (all of it).
"""
