"""Pictures: headless lit renders side by side, colormaps and color bars, notebook display."""

from . import panel
from .panel import *  # noqa: F403 (the names of panel.__all__)

__all__ = panel.__all__
