"""``python -m labrunner`` is the ``labrunner`` command."""

import sys

try:
    from labrunner.cli import main
except KeyboardInterrupt:  # Ctrl-C while the command is still loading
    print("labrunner: interrupted", file=sys.stderr)
    sys.exit(130)

sys.exit(main())
