"""Command line: ``o3d-ofp`` / ``python -m o3d_ofp``, one small module per command.

Each command module has ``add_parser(subparsers)`` (the flags, mapping 1:1 to library
keywords) and ``run(args) -> int`` (a thin shell over the workflows and the boundary).
"""

from .main import build_parser, main

__all__ = ["build_parser", "main"]
