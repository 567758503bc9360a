"""Output writers: sim.h5 (+ sim.xdmf), VTK files, checkpoints.  They know nothing of physics
(and never import taichi): they receive per-entity dicts of numpy arrays.
"""

from .checkpoint import (
    CheckpointWarning,
    latest_checkpoint,
    list_checkpoints,
    load_latest_checkpoint,
    read_checkpoint,
    write_checkpoint,
)
from .frames import EntityMeta, FrameSink

__all__ = [
    "EntityMeta",
    "FrameSink",
    "CheckpointWarning",
    "write_checkpoint",
    "latest_checkpoint",
    "load_latest_checkpoint",
    "list_checkpoints",
    "read_checkpoint",
    "open_frames",
    "clear_status_flags",
]


def open_frames(path):
    """Open a sim.h5 for reading (while written, after a crash, or after close)."""
    from .hdf5 import open_frames as _open

    return _open(path)


def clear_status_flags(path) -> bool:
    """Make a sim.h5 left by a killed run openable by any HDF5 tool (like ``h5clear -s``)."""
    from .hdf5 import clear_status_flags as _clear

    return _clear(path)
