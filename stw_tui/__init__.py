"""stw — Spacetime Windows for the terminal (core: no Textual, no torch)."""

__version__ = "0.1.0"
