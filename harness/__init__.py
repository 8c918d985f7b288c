"""StellaUAV harness: scenarios, search, evaluation, campaigns and the `stella` CLI."""

__version__ = "0.1.0"
