"""``--set key.path=value`` overrides (also used by sweeps): dotted paths, list items by
index, values parsed as YAML."""

from __future__ import annotations

from typing import Any


def split_path(dotted: str) -> tuple:
    """'entities.0.material.E' -> ('entities', 0, 'material', 'E')."""
    if not dotted or dotted.startswith(".") or dotted.endswith(".") or ".." in dotted:
        raise ValueError(
            f"bad key path '{dotted}' (expected dotted keys such as sim.dt or entities.0.material.E)"
        )
    return tuple(int(p) if p.lstrip("-").isdigit() else p for p in dotted.split("."))


def parse_set(text: str) -> tuple[tuple, Any]:
    """Parse 'a.b.0.c=value'; the value is YAML-typed ('1e-3' -> float, '[1, 2]' -> list)."""
    if "=" not in text:
        raise ValueError("expected KEY=VALUE, e.g. --set sim.dt=1e-3")
    key, raw = text.split("=", 1)
    path = split_path(key.strip())
    from simcli.errors import SceneError
    from simcli.scene.yaml_reader import parse_yaml_any

    try:
        value = parse_yaml_any(raw, "value").data if raw.strip() != "" else None
    except SceneError as e:  # the scene reader's limits (depth, aliases, tags) hold for --set too
        raise ValueError("; ".join(e.lines).replace("value:1:", "column ")) from None
    return path, value


def apply_overrides(data: dict, overrides: list[tuple[tuple, Any]]) -> dict:
    """Set each path to its value in place; missing mapping keys are created."""
    for path, value in overrides:
        cur: Any = data
        for i, p in enumerate(path[:-1]):
            nxt = path[i + 1]
            if isinstance(p, int):
                if not isinstance(cur, list):
                    raise ValueError(f"'{_dot(path[:i])}' is not a list, cannot index it with {p}")
                if not -len(cur) <= p < len(cur):
                    raise ValueError(f"index {p} out of range: '{_dot(path[:i])}' has {len(cur)} items")
                cur = cur[p]
            else:
                if not isinstance(cur, dict):
                    raise ValueError(f"'{_dot(path[:i])}' is not a mapping, cannot set key '{p}'")
                if p not in cur or cur[p] is None:
                    cur[p] = [] if isinstance(nxt, int) else {}
                cur = cur[p]
        last = path[-1]
        if isinstance(last, int):
            if not isinstance(cur, list):
                raise ValueError(f"'{_dot(path[:-1])}' is not a list, cannot index it with {last}")
            if last == len(cur):
                cur.append(value)
            elif -len(cur) <= last < len(cur):
                cur[last] = value
            else:
                raise ValueError(f"index {last} out of range: '{_dot(path[:-1])}' has {len(cur)} items")
        else:
            if not isinstance(cur, dict):
                raise ValueError(f"'{_dot(path[:-1])}' is not a mapping, cannot set key '{last}'")
            cur[last] = value
    return data


def _dot(path) -> str:
    return ".".join(str(p) for p in path) or "(top level)"
