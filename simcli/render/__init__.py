"""Quick-look pictures, movies and plots of a run's output folder, without ParaView and without a display.

matplotlib (Agg) draws; imageio-ffmpeg's bundled ffmpeg encodes .mp4 (Pillow, which matplotlib needs
anyway, writes .gif).  Nothing here imports Taichi: it reads OUT/sim.h5, OUT/scene.yaml, OUT/run.json and
OUT/probes.csv only."""

from .data import RenderError, open_run, read_frame, resolve_frame
from .draw import render_movie, render_picture
from .plot import plot_run

__all__ = [
    "RenderError",
    "open_run",
    "read_frame",
    "resolve_frame",
    "render_picture",
    "render_movie",
    "plot_run",
]
