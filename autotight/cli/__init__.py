"""The ``autotight`` command line (``main``); ``python -m autotight.cli`` runs it too."""

from .main import build_parser, main

__all__ = ["build_parser", "main"]
