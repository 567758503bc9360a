"""The registry of measurements (``@measurement("name")`` fills ``MEASUREMENTS``) and the helper every
measurement uses to find its entity in ``sim.h5``. A leaf module: ``measure.py`` and the family
measurement modules (``pbd_measures.py``) import it, it imports neither."""

from __future__ import annotations

from collections.abc import Callable

import h5py

MEASUREMENTS: dict[str, Callable] = {}


def measurement(name: str):
    def deco(fn):
        MEASUREMENTS[name] = fn
        return fn

    return deco


def entity_group(f: h5py.File, entity: str | None) -> tuple[str, h5py.Group]:
    """(name, group) of ``entity`` in an open sim.h5 (the first entity when None); KeyError if absent."""
    names = list(f["entities"].keys())
    if entity is None:
        entity = names[0]
    if entity not in names:
        raise KeyError(f"entity '{entity}' not in sim.h5 (has {', '.join(names)})")
    return entity, f["entities"][entity]
