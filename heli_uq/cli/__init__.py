"""The ``heli-uq`` command (layer 8: may import everything; nothing imports it)."""

from heli_uq.cli.main import build_parser as build_parser
from heli_uq.cli.main import main as main

__all__ = ["build_parser", "main"]
