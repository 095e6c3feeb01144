"""Pictures: headless lit renders side by side, colormaps and color bars, notebook display."""

from .panel import (
    RenderError,
    RenderUnavailable,
    View,
    colormap,
    read_png,
    render_images,
    render_panel,
    show,
    write_png,
)

__all__ = [
    "RenderError",
    "RenderUnavailable",
    "View",
    "colormap",
    "read_png",
    "render_images",
    "render_panel",
    "show",
    "write_png",
]
