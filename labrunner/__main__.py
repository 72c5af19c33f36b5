"""``python -m labrunner`` is the ``labrunner`` command."""

import sys

from labrunner.cli import main

sys.exit(main())
