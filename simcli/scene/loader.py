"""Scene loading: YAML with line/column for every key, then validation, reporting every
problem of a file at once as ``file:line:col: dotted.path: message``.

No Taichi here: ``simcli validate`` and ``simcli schema`` must answer in well under a second.
"""

from __future__ import annotations

import difflib
import math
import os
import re
import stat
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError

from simcli.errors import SceneError
from simcli.scene.lines import sort_lines  # also imported from here (sweep.model)
from simcli.scene.materials import PLANNED_TYPES, material_type_names
from simcli.scene.models import Scene
from simcli.scene.overrides import apply_overrides, parse_set

# the YAML reader with positions and limits: a leaf module (overrides.parse_set reads --set values with it);
# its names are re-exported here for the importers of the loader
from simcli.scene.yaml_reader import (  # noqa: F401
    MAX_DEPTH,
    MAX_FILE_BYTES,
    MAX_NODES,
    Located,
    Path_,
    _dotted,
    _Loader,
    _mark,
    parse_yaml_any,
)


def read_yaml_file(path: Path) -> Located:
    """Read and parse a YAML file, keeping positions. Raises SceneError when the file is missing,
    unreadable or malformed."""
    shown = str(path)
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode):  # /dev/zero or a FIFO would be read forever
            raise SceneError([f"{shown}: not a regular file"])
        if st.st_size > MAX_FILE_BYTES:
            raise SceneError(
                [
                    f"{shown}: {st.st_size / 2**20:.0f} MiB is too large for a scene or sweep file (at most "
                    f"{MAX_FILE_BYTES // 2**20} MiB; meshes go in their own files)"
                ]
            )
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise SceneError([f"{shown}: file not found"]) from None
    except (OSError, UnicodeDecodeError) as e:
        raise SceneError([f"{shown}: cannot read: {e}"]) from None
    return parse_yaml(text, shown)


def parse_yaml(text: str, file: str) -> Located:
    """Parse YAML text, keeping positions. Raises SceneError for malformed YAML."""
    loc = parse_yaml_any(text, file)
    if loc.data is None:
        loc.data = {}
    if not isinstance(loc.data, dict):
        raise SceneError(
            [f"{file}:1:1: (top level): expected a mapping of scene keys (found {_kind(loc.data)})"]
        )
    return loc


# ----------------------------------------------------------------- error output


def _kind(v: Any) -> str:
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "a boolean"
    if isinstance(v, int):
        return "an integer"
    if isinstance(v, float):
        return "a number"
    if isinstance(v, str):
        return "a string"
    if isinstance(v, list):
        return "a list"
    if isinstance(v, dict):
        return "a mapping"
    return type(v).__name__


def _short(v: Any) -> str:
    if isinstance(v, (dict, list)):
        return _kind(v)
    s = repr(v) if isinstance(v, str) else str(v)
    return s if len(s) <= 60 else s[:57] + "..."


def _unwrap(tp):
    """Strip Annotated/Optional/list wrappers down to model classes (a tuple of candidates)."""
    origin = typing.get_origin(tp)
    if origin is typing.Annotated:
        return _unwrap(typing.get_args(tp)[0])
    if origin is typing.Union or str(origin) == "types.UnionType":
        out = ()
        for a in typing.get_args(tp):
            out += _unwrap(a)
        return out
    if origin in (list, tuple):
        return _unwrap(typing.get_args(tp)[0])
    if origin is dict:
        return _unwrap(typing.get_args(tp)[1])
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return (tp,)
    return ()


def _model_at(path: Path_, data: Any) -> type[BaseModel] | None:
    """The pydantic model class that describes the mapping at ``path`` of ``data``."""
    models: tuple = (Scene,)
    cur = data
    for p in path:
        if isinstance(p, int):
            cur = cur[p] if isinstance(cur, list) and p < len(cur) else None
            continue
        chosen = _pick(models, cur)
        if chosen is None or p not in chosen.model_fields:
            # dict-valued fields (domain.faces) keep the model list
            if chosen is not None:
                return None
        else:
            models = _unwrap(chosen.model_fields[p].annotation)
        cur = cur.get(p) if isinstance(cur, dict) else None
    return _pick(models, cur)


def _pick(models: tuple, data: Any):
    if not models:
        return None
    if len(models) == 1:
        return models[0]
    if isinstance(data, dict) and "type" in data:
        for m in models:
            f = m.model_fields.get("type")
            if f is not None and data["type"] in typing.get_args(f.annotation):
                return m
    return models[0]


def _clean_loc(loc: tuple, data: Any) -> Path_:
    """Drop the union-member tags pydantic inserts into error locations."""
    out: list = []
    cur = data
    for p in loc:
        if isinstance(p, int):
            if isinstance(cur, list):
                out.append(p)
                cur = cur[p] if p < len(cur) else None
            continue
        if isinstance(cur, dict) and p in cur:
            out.append(p)
            cur = cur[p]
            continue
        if isinstance(cur, dict) and isinstance(p, str) and p == cur.get("type"):
            continue  # a discriminated union's tag: the item's own type value ('point', 'total', ...)
        if (
            isinstance(cur, dict)
            and isinstance(p, str)
            and ("[" in p or "." in p or p[:1].isupper() or p in ("int", "float", "str", "list"))
        ):
            continue  # a union tag such as 'MPM.Elastic', 'Box', 'int', "literal['auto']"
        if not isinstance(cur, dict) and isinstance(p, str) and (cur is not None or "[" in p or "-" in p):
            continue  # below a scalar or list, a string is a union tag ('constrained-int', 'list[...]')
        out.append(p)
        cur = None
    return tuple(out)


def _describe(err: dict, data: Any, path: Path_) -> str:
    t = err["type"]
    ctx = err.get("ctx") or {}
    got = err.get("input")
    if t == "extra_forbidden":
        model = _model_at(path[:-1], data)
        known = list(model.model_fields) if model is not None else []
        hint = difflib.get_close_matches(str(path[-1]), known, n=1, cutoff=0.6)
        tail = (
            f" (did you mean '{hint[0]}'?)"
            if hint
            else (f" (known keys: {', '.join(known)})" if known else "")
        )
        return f"unknown key{tail}"
    if t == "missing":
        return "required key missing"
    if t in ("union_tag_invalid", "union_tag_not_found"):
        tag = ctx.get("tag", got if not isinstance(got, dict) else got.get("type"))
        expected = ctx.get("expected_tags", "")
        if t == "union_tag_not_found":
            return f"missing 'type' (expected one of {expected})"
        hint = difflib.get_close_matches(
            str(tag), [s.strip(" '") for s in str(expected).split(",")], n=1, cutoff=0.6
        )
        tail = f" (did you mean '{hint[0]}'?)" if hint else ""
        if len(path) >= 2 and path[-2] == "material":
            if tag in PLANNED_TYPES:
                return (
                    f"material type '{tag}' is not implemented in this version of simcli "
                    f"(available: {', '.join(material_type_names())})"
                )
            return f"unknown material type '{tag}'{tail}; available: {', '.join(material_type_names())}"
        return f"unknown type '{tag}'; expected one of {expected}{tail}"
    if t == "literal_error":
        expected = ctx.get("expected", "")
        if path and path[-1] == "type" and len(path) >= 2 and path[-2] == "material":
            if got in PLANNED_TYPES:
                return (
                    f"material type '{got}' is not implemented in this version of simcli "
                    f"(available: {', '.join(material_type_names())})"
                )
            hint = difflib.get_close_matches(str(got), material_type_names() + list(PLANNED_TYPES), n=1)
            tail = f" (did you mean '{hint[0]}'?)" if hint else ""
            return f"unknown material type {_short(got)}; expected {expected}{tail}"
        opts = [s.strip(" '") for s in str(expected).replace(" or ", ",").split(",")]
        hint = difflib.get_close_matches(str(got), opts, n=1, cutoff=0.6)
        tail = f" (did you mean '{hint[0]}'?)" if hint and hint[0] != str(got) else ""
        return f"expected {expected} (got {_short(got)}){tail}"
    bounds = {
        "greater_than": ("> ", "gt"),
        "greater_than_equal": (">= ", "ge"),
        "less_than": ("< ", "lt"),
        "less_than_equal": ("<= ", "le"),
    }
    if t in bounds:
        sym, key = bounds[t]
        return f"must be {sym}{ctx.get(key)} (got {_short(got)})"
    if t in ("int_type", "int_parsing", "int_from_float"):
        return f"expected an integer (got {_short(got)})"
    if t in ("float_type", "float_parsing"):
        return f"expected a number (got {_short(got)})"
    if t in ("string_type",):
        return f"expected a string (got {_short(got)})"
    if t in ("bool_type", "bool_parsing"):
        return f"expected true or false (got {_short(got)})"
    if t in ("list_type", "tuple_type"):
        return f"expected a list (got {_short(got)})"
    if t in ("dict_type", "model_type", "model_attributes_type"):
        return f"expected a mapping of keys (got {_short(got)})"
    if t == "string_too_short":
        return "must not be empty"
    if t == "value_error":
        return str(ctx.get("error", err["msg"])).removeprefix("Value error, ")
    return f"{err['msg']} (got {_short(got)})"


def format_validation_error(exc: ValidationError, loc: Located) -> list[str]:
    grouped: dict[Path_, list[tuple[dict, str]]] = {}
    order: list[Path_] = []
    for err in exc.errors(include_url=False):
        path = _clean_loc(err["loc"], loc.data)
        if err["type"] == "union_tag_invalid":  # point at the offending `type:` value itself
            path = path + ("type",)
        msg = _describe(err, loc.data, path)
        if path not in grouped:
            grouped[path] = []
            order.append(path)
        if msg not in [m for _, m in grouped[path]]:
            grouped[path].append((err, msg))
    lines = []
    for path in order:
        items = grouped[path]
        if len(items) > 1:
            # a plain union (e.g. substeps: int >= 1 | 'auto'): say every acceptable form once
            msgs = [m for _, m in items if not m.startswith("unknown key")] or [m for _, m in items]
            got = re.search(r" \(got [^)]*\)$", msgs[-1])
            parts = [re.sub(r" \(got [^)]*\)$", "", m) for m in msgs]
            msg = " or ".join(dict.fromkeys(parts)) + (got.group(0) if got else "")
        else:
            msg = items[0][1]
        prefer_key = items[0][0]["type"] == "extra_forbidden"
        lines.append(f"{loc.where(path, prefer_key=prefer_key)}: {_dotted(path)}: {msg}")
    return sort_lines(lines)


# ----------------------------------------------------------------- entry points


@dataclass
class LoadedScene:
    scene: Scene
    path: Path
    located: Located

    @property
    def scene_dir(self) -> Path:
        return self.path.parent

    @property
    def name(self) -> str:
        return self.scene.name or self.path.stem


# Integers beyond this are refused everywhere (the solvers index with 32-bit integers; no count, seed or
# size of a scene comes near it).
MAX_INT = 2**31 - 1


def _check_numbers(data: Any, path: Path_, loc: Located, errors: list[str]) -> None:
    """NaN, Inf and out-of-range integers anywhere in a scene are errors at their place: no key of the
    format means 'infinite' (an open bound is written by leaving the key out)."""
    if isinstance(data, dict):
        for k, v in data.items():
            _check_numbers(v, path + (k,), loc, errors)
    elif isinstance(data, list):
        for i, v in enumerate(data):
            _check_numbers(v, path + (i,), loc, errors)
    elif isinstance(data, float) and not math.isfinite(data):
        errors.append(f"{loc.where(path)}: {_dotted(path)}: must be a finite number (got {data})")
    elif isinstance(data, int) and not isinstance(data, bool) and abs(data) > MAX_INT:
        errors.append(
            f"{loc.where(path)}: {_dotted(path)}: integer {_short(data)} is beyond {MAX_INT:,} (the "
            "largest any "
            "key takes)"
        )


def scene_from_located(loc: Located, path: Path, check: bool = True) -> LoadedScene:
    """Validate located YAML data as a scene (``load_scene`` and every run of a sweep): plain numbers,
    strict types (no true for a number, no 5.5 for a count), then the semantic checks. Raises SceneError."""
    errors: list[str] = []
    if not loc.data:
        raise SceneError(
            [
                f"{loc.file}:1:1: (top level): the scene is empty; a scene needs at least entities: "
                "(each a name, "
                "a material and a morph); see configs/ for examples"
            ]
        )
    _check_numbers(loc.data, (), loc, errors)
    if errors:
        raise SceneError(sort_lines(errors))
    try:
        # strict: YAML gives plain types, so strict only refuses what lax mode would silently convert (true
        # read as 1 Pa, 2.7 truncated to a count, '1e5' as a number)
        scene = Scene.model_validate(loc.data, strict=True)
    except ValidationError as e:
        raise SceneError(format_validation_error(e, loc)) from None
    loaded = LoadedScene(scene=scene, path=path, located=loc)
    if check:
        from simcli.scene.checks import check_scene
        from simcli.scene.limits import check_bounds

        lines = check_bounds(loaded) or check_scene(loaded)
        if lines:
            raise SceneError(lines)
    return loaded


def load_scene(path: str | Path, sets: list[str] | tuple[str, ...] = (), check: bool = True) -> LoadedScene:
    """Read, override, validate and semantically check a scene file.

    Raises SceneError with every problem found, one formatted line each.
    """
    path = Path(path)
    loc = read_yaml_file(path)
    if sets:
        errors = []
        for s in sets:
            try:
                key_path, value = parse_set(s)
                apply_overrides(loc.data, [(key_path, value)])
                # everything under an overridden key now comes from --set
                for p in list(loc.key_pos) + list(loc.value_pos):
                    if p[: len(key_path)] == key_path:
                        loc.key_pos.pop(p, None)
                        loc.value_pos.pop(p, None)
                loc.override_src[key_path] = f"--set {s}"
            except ValueError as e:
                errors.append(f"--set {s}: {e}")
        if errors:
            raise SceneError(errors)
    return scene_from_located(loc, path, check)
