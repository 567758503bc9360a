"""The sweep file (SCENE_FORMAT.md section 4): a base scene plus keys to vary, expanded into
runs, each with a name from a template and its own output folder.

Expansion: the grid is the cartesian product of its lists, the grid keys as written with the
first varying slowest; the zipped lists, all of one length, form one more axis that varies
fastest.  Runs are numbered from 0 in that order, so a task index is stable as long as the
sweep file is.

Errors are reported like scene errors: every problem at once, one line each, as
``file:line:col: key: message`` (exit 65).  Values a sweep sets in a scene are reported at
their place in the sweep file.
"""

from __future__ import annotations

import copy
import difflib
import hashlib
import itertools
import json
import math
import os
import re
import string
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from simcli.errors import SceneError
from simcli.scene.loader import (
    LoadedScene,
    Located,
    _clean_loc,
    _describe,
    parse_yaml,
    read_yaml_file,
    sort_lines,
)
from simcli.scene.overrides import apply_overrides, split_path
from simcli.scene.schema import model_schema, schema_json

SCHEMA_ID = "https://simcli.dev/schemas/sweep.schema.json"
# where a sweep keeps its own files (sbatch script, submissions, logs) inside its output folder
ADMIN_DIR = "_sweep"
# a dotted scene key: keys and list indices separated by dots
KEY_PATTERN = r"^[^.\s]+(\.[^.\s]+)*$"
# Most runs one sweep expands to (docs/LIMITS.md): more is refused before expansion. A sweep of this size is
# already a Slurm array beyond most sites' MaxArraySize; split larger studies.
MAX_RUNS = 5000
_NAME_OK = re.compile(r"[^A-Za-z0-9._+=-]")

Values = Annotated[list[Any], Field(min_length=1)]


class Sweep(BaseModel):
    """A parameter study: one base scene, the keys to vary, how runs are named and where they go."""

    model_config = ConfigDict(extra="forbid", frozen=True, title="simcli sweep")

    version: Literal[1] = Field(1, description="Sweep file format version.")
    base: str = Field(
        min_length=1, description="Scene file every run starts from, relative to this sweep file."
    )
    name: str | None = Field(
        None,
        min_length=1,
        description="Run name template: {dotted.key} is replaced by the run's value of that key (a varied "
        "key or any key of the base scene), {index} by the run number; Python format specs work "
        "({sim.dt:.0e}). Names must differ between runs. Default: the run index.",
    )
    grid: dict[str, Values] = Field(
        default_factory=dict,
        description="Cartesian product: dotted scene key -> list of values; every combination is one run.",
        json_schema_extra={"propertyNames": {"pattern": KEY_PATTERN}},
    )
    zip: dict[str, Values] = Field(
        default_factory=dict,
        description="Keys varied together: dotted scene key -> list of values, all lists of equal length; "
        "item i of every list goes into the same run (combined with every grid point).",
        json_schema_extra={"propertyNames": {"pattern": KEY_PATTERN}},
    )
    output: str | None = Field(
        None,
        min_length=1,
        description="Folder of the sweep, relative to the working directory; run i writes <output>/<its "
        "name>/. Default: out/<sweep file name without extension>.",
    )
    metrics: list[str] = Field(
        default_factory=list,
        description="Extra columns for `simcli sweep collect`: dotted paths into run.json "
        "(throughput.steps_per_s), or measure.<quantity>.<entity>[.<axis>][.final|max|min|mean]: a "
        "verification measurement of sim.h5 (com, min_coord, max_speed, kinetic_energy, ...) reduced over "
        "the frames (default: the last frame), or probe.<name>[.x|y|z][.final|max|min|mean]: a probe's "
        "column of OUT/probes.csv (every probe is collected without being named).",
    )


def sweep_schema() -> dict:
    return model_schema(Sweep, SCHEMA_ID, "simcli sweep")


def sweep_schema_text() -> str:
    return schema_json(sweep_schema())


def looks_like_sweep(path: str | Path) -> bool:
    """True for a sweep file (a top-level ``base:`` key), so ``simcli validate`` can route it here."""
    try:  # the scene reader (its limits on aliases and depth hold here too)
        data = read_yaml_file(Path(path)).data
    except SceneError:
        return False
    return isinstance(data, dict) and "base" in data and "entities" not in data


# --------------------------------------------------------------------------- runs


@dataclass(frozen=True)
class Run:
    index: int
    name: str
    params: dict  # dotted key -> value: grid keys, then zip keys, as written
    sources: dict  # dotted key -> "sweep.yaml:line:col" of the value

    def overrides(self) -> list[tuple[tuple, Any]]:
        return [(split_path(k), copy.deepcopy(v)) for k, v in self.params.items()]

    def set_args(self) -> list[str]:
        """The ``--set KEY=VALUE`` arguments of ``simcli run`` for this run."""
        return [f"{k}={set_value_text(v)}" for k, v in self.params.items()]


def set_value_text(v: Any) -> str:
    """A value as ``--set`` text that parses back to the same value (JSON is YAML)."""
    if isinstance(v, float) and not math.isfinite(v):
        return ".nan" if math.isnan(v) else (".inf" if v > 0 else "-.inf")
    return json.dumps(v)


def compact_number(v: float) -> str:
    """Shortest exact text of a float for a folder name: 1e5 -> 1e5, 0.001 -> 1e-3, 0.01 -> 0.01,
    64.0 -> 64, 2.5e5 -> 2.5e5 (plain notation wins ties)."""
    if not math.isfinite(v):
        return str(v)
    if v == 0:
        return "0"
    plain = f"{v:f}".rstrip("0").rstrip(".") if abs(v) >= 1e-6 else repr(v)
    if float(plain) != v:
        plain = repr(v)
    for p in range(17):
        sci = f"{v:.{p}e}"
        if float(sci) == v:
            break
    mant, exp = sci.split("e")
    if "." in mant:
        mant = mant.rstrip("0").rstrip(".")
    sci = f"{mant}e{int(exp)}"
    return sci if len(sci) < len(plain) else plain


def name_value_text(v: Any, spec: str = "") -> str:
    if spec:
        return format(v, spec)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return compact_number(v)
    if isinstance(v, (list, tuple)):
        return "_".join(name_value_text(x) for x in v)
    if isinstance(v, dict):
        return "_".join(f"{k}{name_value_text(x)}" for k, x in v.items())
    return "null" if v is None else str(v)


def safe_name(text: str) -> str:
    """Characters other than letters, digits and ``._+=-`` become ``_``: names are folder names."""
    return _NAME_OK.sub("_", text)


@dataclass
class LoadedSweep:
    sweep: Sweep
    path: Path
    located: Located
    base_path: Path
    base_located: Located
    base_text: str
    runs: list[Run]

    @property
    def label(self) -> str:
        return self.path.stem

    @property
    def output_dir(self) -> Path:
        return Path(self.sweep.output) if self.sweep.output else Path("out") / self.path.stem

    @property
    def admin_dir(self) -> Path:
        return self.output_dir / ADMIN_DIR

    def run_dir(self, run: Run) -> Path:
        return self.output_dir / run.name

    def run_fingerprint(self, run: Run) -> str:
        """Changes when the base scene file or the run's values change (a checkpoint of another
        scene must not be resumed)."""
        h = hashlib.sha256(self.base_text.encode())
        h.update(json.dumps(run.params, sort_keys=True, default=str).encode())
        return h.hexdigest()[:16]


# ------------------------------------------------------------------ error lines


def _sweep_key(path: tuple) -> str:
    """'grid', 'entities.0.material.E', 1 -> grid.entities.0.material.E[1]"""
    if not path:
        return "(top level)"
    out = str(path[0])
    rest = path[1:]
    if path[0] in ("grid", "zip") and rest:
        out += f".{rest[0]}"
        rest = rest[1:]
    for p in rest:
        out += f"[{p}]" if isinstance(p, int) else f".{p}"
    return out


def _format_model_errors(exc: ValidationError, loc: Located) -> list[str]:
    lines = []
    for err in exc.errors(include_url=False):
        path = _clean_loc(err["loc"], loc.data)
        t = err["type"]
        prefer_key = False
        if t == "extra_forbidden":
            known = list(Sweep.model_fields)
            hint = difflib.get_close_matches(str(path[-1]), known, n=1, cutoff=0.6)
            msg = "unknown key" + (
                f" (did you mean '{hint[0]}'?)" if hint else f" (known keys: {', '.join(known)})"
            )
            prefer_key = True
        elif t == "too_short":
            msg = "must list at least one value" if path[:1] in (("grid",), ("zip",)) else "must not be empty"
        elif t == "dict_type" and path in (("grid",), ("zip",)):
            msg = (
                "expected a mapping of dotted scene keys to lists of values (got "
                f"{type(err.get('input')).__name__})"
            )
        elif t == "list_type" and path[:1] in (("grid",), ("zip",)):
            msg = (
                f"expected a list of values (got {err.get('input')!r}); "
                f"write [{err.get('input')!r}] for one value"
            )
        else:
            msg = _describe(err, loc.data, path)
        line = f"{loc.where(path, prefer_key=prefer_key)}: {_sweep_key(path)}: {msg}"
        if line not in lines:
            lines.append(line)
    return lines


# ---------------------------------------------------------------------- loading


def load_sweep(path: str | Path) -> LoadedSweep:
    """Read, validate and expand a sweep file. Raises SceneError with every problem found."""
    path = Path(path)
    loc = read_yaml_file(path)
    errors: list[str] = []
    data = loc.data
    for section in ("grid", "zip"):
        block = data.get(section)
        if not isinstance(block, dict):
            continue
        for key in block:
            where = loc.where((section, key), prefer_key=True)
            if not isinstance(key, str):
                errors.append(f"{where}: {section}: key {key!r} is not a dotted scene key (such as sim.dt)")
                continue
            try:
                split_path(key)
            except ValueError as e:
                errors.append(f"{where}: {_sweep_key((section, key))}: {e}")
    try:
        sweep = Sweep.model_validate(data)
    except ValidationError as e:
        errors += _format_model_errors(e, loc)
    if errors:
        raise SceneError(sort_lines(errors))

    # keys: no key twice, no key inside another (the later would silently win)
    keys = [("grid", k) for k in sweep.grid] + [("zip", k) for k in sweep.zip]
    for i, (sa, ka) in enumerate(keys):
        for sb, kb in keys[:i]:
            pa, pb = split_path(ka), split_path(kb)
            if pa == pb:
                errors.append(
                    f"{loc.where((sa, ka), prefer_key=True)}: {_sweep_key((sa, ka))}: also varied in "
                    f"{sb} (at {loc.where((sb, kb), prefer_key=True)}); vary each key once"
                )
            elif pa[: len(pb)] == pb or pb[: len(pa)] == pa:
                errors.append(
                    f"{loc.where((sa, ka), prefer_key=True)}: {_sweep_key((sa, ka))}: overlaps "
                    f"{sb}.{kb} (one key lies inside the other); vary one of them"
                )
    lengths = {k: len(v) for k, v in sweep.zip.items()}
    if len(set(lengths.values())) > 1:
        detail = ", ".join(f"{k}: {n}" for k, n in lengths.items())
        errors.append(
            f"{loc.where(('zip',), prefer_key=True)}: zip: the lists must have equal lengths ({detail})"
        )

    base_path = Path(os.path.normpath(path.parent / sweep.base))
    base_text = ""
    base_loc = None
    if not base_path.is_file():
        errors.append(f"{loc.where(('base',))}: base: scene file not found: {base_path}")
    else:
        try:
            base_text = base_path.read_text(encoding="utf-8")
            base_loc = parse_yaml(base_text, str(base_path))
        except SceneError as e:
            errors += e.lines
        except (OSError, UnicodeDecodeError) as e:
            errors.append(f"{loc.where(('base',))}: base: cannot read {base_path}: {e}")
    if errors:
        raise SceneError(sort_lines(errors))

    n_runs = math.prod(len(v) for v in sweep.grid.values()) * (
        len(next(iter(sweep.zip.values()))) if sweep.zip else 1
    )
    if n_runs > MAX_RUNS:  # before expanding: every run holds a copy of the base scene
        sizes = " x ".join(f"{k}: {len(v)}" for k, v in {**sweep.grid, **sweep.zip}.items())
        raise SceneError(
            [
                f"{loc.where(('grid',) if sweep.grid else ('zip',), prefer_key=True)}: "
                f"{'grid' if sweep.grid else 'zip'}: the sweep expands to {n_runs:,} runs ({sizes}), "
                "more than "
                f"the {MAX_RUNS:,} one sweep may hold; shorten the lists or split it into several sweeps"
            ]
        )
    runs = _expand(sweep, loc, base_loc, errors)
    if errors:
        raise SceneError(sort_lines(list(dict.fromkeys(errors))))
    return LoadedSweep(
        sweep=sweep,
        path=path,
        located=loc,
        base_path=base_path,
        base_located=base_loc,
        base_text=base_text,
        runs=runs,
    )


def _expand(sweep: Sweep, loc: Located, base_loc: Located, errors: list[str]) -> list[Run]:
    grid_keys = list(sweep.grid)
    zip_keys = list(sweep.zip)
    n_zip = len(next(iter(sweep.zip.values()))) if zip_keys else 1
    axes = [range(len(sweep.grid[k])) for k in grid_keys] + [range(n_zip)]
    combos = list(itertools.product(*axes))
    width = len(str(max(len(combos) - 1, 0)))
    runs = []
    names: dict[str, int] = {}
    for index, combo in enumerate(combos):
        params: dict = {}
        sources: dict = {}
        for k, i in zip(grid_keys, combo[:-1]):
            params[k] = sweep.grid[k][i]
            sources[k] = loc.where(("grid", k, i))
        for k in zip_keys:
            params[k] = sweep.zip[k][combo[-1]]
            sources[k] = loc.where(("zip", k, combo[-1]))
        data = copy.deepcopy(base_loc.data)
        for k, v in params.items():
            section = "grid" if k in sweep.grid else "zip"
            try:
                apply_overrides(data, [(split_path(k), copy.deepcopy(v))])
            except ValueError as e:
                errors.append(
                    f"{loc.where((section, k), prefer_key=True)}: {_sweep_key((section, k))}: "
                    f"cannot set it in {base_loc.file}: {e}"
                )
        name = _render_name(sweep, loc, index, width, params, data, errors)
        if name is None:
            continue
        if name in names:
            varied = ", ".join(grid_keys + zip_keys) or "(none)"
            errors.append(
                f"{loc.where(('name',))}: name: runs {names[name]} and {index} both get the name "
                f"'{name}'; put every varied key into the template (varied: {varied})"
            )
            continue
        names[name] = index
        runs.append(Run(index=index, name=name, params=params, sources=sources))
    return runs


def _lookup(data: Any, path: tuple) -> tuple[bool, Any]:
    cur = data
    for p in path:
        if (isinstance(p, int) and isinstance(cur, list) and -len(cur) <= p < len(cur)) or (
            isinstance(cur, dict) and p in cur
        ):
            cur = cur[p]
        else:
            return False, None
    return True, cur


def _render_name(
    sweep: Sweep, loc: Located, index: int, width: int, params: dict, data: Any, errors: list[str]
) -> str | None:
    where = loc.where(("name",))
    if sweep.name is None:
        return f"{index:0{width}d}"
    out = []
    try:
        parts = list(string.Formatter().parse(sweep.name))
    except ValueError as e:
        errors.append(f"{where}: name: bad template: {e} (write {{{{ and }}}} for literal braces)")
        return None
    for literal, field_name, spec, conversion in parts:
        out.append(literal)
        if field_name is None:
            continue
        if conversion:
            errors.append(
                f"{where}: name: conversions such as !{conversion} are not supported in {{{field_name}}}"
            )
            return None
        if field_name == "":
            errors.append(f"{where}: name: empty placeholder {{}}; name a key, e.g. {{sim.dt}}, or {{index}}")
            return None
        if field_name == "index":
            value: Any = index
        elif field_name in params:
            value = params[field_name]
        else:
            try:
                found, value = _lookup(data, split_path(field_name))
            except ValueError:
                found = False
            if not found:
                candidates = list(params) + ["index"]
                hint = difflib.get_close_matches(field_name, candidates, n=1, cutoff=0.6)
                tail = f" (did you mean '{hint[0]}'?)" if hint else f" (varied keys: {', '.join(candidates)})"
                errors.append(
                    f"{where}: name: {{{field_name}}} is neither a varied key nor a key of the base "
                    f"scene{tail}"
                )
                return None
        try:
            out.append(name_value_text(value, spec or ""))
        except (ValueError, TypeError) as e:
            errors.append(f"{where}: name: cannot format {{{field_name}:{spec}}} with value {value!r}: {e}")
            return None
    name = safe_name("".join(out))
    if name in ("", ".", "..") or name.startswith(ADMIN_DIR):
        errors.append(f"{where}: name: run {index} gets the unusable folder name '{name}'")
        return None
    return name


# ------------------------------------------------------------ per-run scenes


def run_located(ls: LoadedSweep, run: Run) -> Located:
    """The base scene's located data with the run's values applied; each value set by the
    sweep is reported at its place in the sweep file."""
    base = ls.base_located
    loc = Located(
        data=copy.deepcopy(base.data),
        file=base.file,
        key_pos=dict(base.key_pos),
        value_pos=dict(base.value_pos),
        override_src=dict(base.override_src),
    )
    for key, value in run.params.items():
        path = split_path(key)
        apply_overrides(loc.data, [(path, copy.deepcopy(value))])
        for p in list(loc.key_pos) + list(loc.value_pos):
            if p[: len(path)] == path:
                loc.key_pos.pop(p, None)
                loc.value_pos.pop(p, None)
        loc.override_src[path] = run.sources[key]
    return loc


def load_run_scene(ls: LoadedSweep, run: Run, check: bool = True) -> LoadedScene:
    """Validate one run's scene (no solver, no Taichi). Raises SceneError."""
    from simcli.scene.loader import scene_from_located

    return scene_from_located(run_located(ls, run), ls.base_path, check)


def validate_runs(ls: LoadedSweep) -> list[str]:
    """Every run's scene validated; a problem shared by several runs is reported once, with
    the runs it concerns (none named when it concerns all)."""
    seen: dict[str, list[Run]] = {}
    for run in ls.runs:
        try:
            load_run_scene(ls, run)
        except SceneError as e:
            for line in e.lines:
                seen.setdefault(line, []).append(run)
    out = []
    for line, runs in seen.items():
        if len(runs) == len(ls.runs):
            out.append(line)
        elif len(runs) == 1:
            out.append(f"{line} [run {runs[0].index} '{runs[0].name}']")
        else:
            out.append(f"{line} [runs {index_ranges([r.index for r in runs])}]")
    return sort_lines(out)


def index_ranges(indices: list[int]) -> str:
    """[0, 1, 2, 5, 7, 8] -> '0-2,5,7-8' (Slurm's --array syntax)."""
    out = []
    xs = sorted(set(indices))
    i = 0
    while i < len(xs):
        j = i
        while j + 1 < len(xs) and xs[j + 1] == xs[j] + 1:
            j += 1
        out.append(str(xs[i]) if i == j else f"{xs[i]}-{xs[j]}")
        i = j + 1
    return ",".join(out)


def parse_indices(text: str, n: int) -> list[int]:
    """'0-2,5' -> [0, 1, 2, 5]; every index must be < n. Raises ValueError."""
    out: list[int] = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        m = re.fullmatch(r"(\d+)(?:-(\d+))?", part)
        if not m:
            raise ValueError(f"bad task list '{text}' (expected indices and ranges such as 0-3,7)")
        a = int(m.group(1))
        b = int(m.group(2)) if m.group(2) else a
        if b < a:
            raise ValueError(f"bad range '{part}' in '{text}'")
        for i in range(a, b + 1):
            if i >= n:
                raise ValueError(f"task {i} does not exist: the sweep has {n} runs (0-{n - 1})")
            if i not in out:
                out.append(i)
    if not out:
        raise ValueError("empty task list")
    return out
