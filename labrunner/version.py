"""labrunner's version, in a module of its own: the log writer and the CLI read it without
importing the package's ``__init__`` (whose lazy results API would close an import circle)."""

__version__ = "0.1.0"
