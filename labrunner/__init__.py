"""labrunner: parameter campaigns of model-free control on lab rigs and their simulated twins."""

__version__ = "0.1.0"
