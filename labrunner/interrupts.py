"""The program's own Ctrl-C handler, shared by the CLI and a campaign session's signal counter.

Kept apart and free of imports so that the CLI installs it before anything heavy loads.
"""

from __future__ import annotations


class FirstPressStops:
    """SIGINT handler of the ``labrunner`` program: the first press raises KeyboardInterrupt (the
    command stops), later presses are ignored while it winds down.

    A campaign session counts presses itself (:class:`~labrunner.campaign.scheduler.StopSignals`)
    and, when it was interrupted, hands this handler back already spent (:meth:`spend`): a second
    press while the session's ledger, logs and last line are being written must not cut them off."""

    def __init__(self) -> None:
        self.spent = False

    def spend(self) -> None:
        """The command has been interrupted elsewhere: from now on every press is ignored."""
        self.spent = True

    def __call__(self, signum: int, frame: object) -> None:
        if not self.spent:
            self.spent = True
            raise KeyboardInterrupt
