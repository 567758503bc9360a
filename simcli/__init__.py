"""simcli: configuration-driven batch simulator for non-rigid physics."""

__version__ = "0.1.0"
