"""The registry of measurements (``@measurement("name")`` fills ``MEASUREMENTS``) and the helper every
measurement uses to find its entity in ``sim.h5``. A leaf module: ``measure.py`` and the family
measurement modules (``pbd_measures.py``) import it, it imports neither."""

from __future__ import annotations

from collections.abc import Callable

import h5py
import numpy as np

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


def stack_field(f: h5py.File, entity: str, field: str = "position") -> np.ndarray:
    """``field`` of one entity, or of every entity side by side when ``entity`` is ``"*"``:
    (frames, particles, ...) as float64."""
    if entity == "*":
        groups = list(f["entities"].values())
        return np.concatenate([np.asarray(g[field][...], dtype=np.float64) for g in groups], axis=1)
    _, g = entity_group(f, entity)
    return np.asarray(g[field][...], dtype=np.float64)


def scene_of(f: h5py.File):
    """The run's resolved scene (sim.h5's ``scene`` attribute) as a validated Scene."""
    import yaml

    from simcli.scene.models import Scene

    return Scene.model_validate(yaml.safe_load(f.attrs["scene"]))
