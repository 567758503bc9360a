"""Property-based test of the scene loader (issue 24): shipped scenes from configs/, mutated (values
replaced by odd numbers, NaN/Inf, huge or tiny values, booleans, strings, lists, mappings, keys deleted),
go through the same path as `simcli validate` (reader positions, strict models, bounds, semantic checks).
Whatever the input, the only exception is the project's SceneError, and each of its lines names a place
(file:line:col, or the --set that set it). Examples are limited so that the test stays a few seconds long;
no wall-clock assertion (a hang shows up as the suite's timeout)."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from simcli.errors import SceneError  # noqa: E402
from simcli.scene.loader import Located, read_yaml_file, scene_from_located  # noqa: E402
from simcli.sweep.model import looks_like_sweep  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SCENES = sorted(
    p
    for p in list((ROOT / "configs").glob("*.yaml")) + list((ROOT / "configs").glob("*/*.yaml"))
    if not p.name.endswith(".case.yaml") and not looks_like_sweep(p)
)
_BASES: dict[Path, Located] = {}


def _base(p: Path) -> Located:
    if p not in _BASES:
        _BASES[p] = read_yaml_file(p)
    return _BASES[p]


def _paths(d, p=()):
    yield p
    if isinstance(d, dict):
        for k, v in d.items():
            yield from _paths(v, p + (k,))
    elif isinstance(d, list):
        for i, v in enumerate(d):
            yield from _paths(v, p + (i,))


_scalars = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e-300, -1e-300, 1e300, 1e-9, 1e9, 0.5, 2.0, -1.0]),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.integers(min_value=-3, max_value=100),
    st.booleans(),
    st.none(),
    st.text(max_size=6),
    st.sampled_from(
        ["../../x", "a/b", ".h", "\x00", "auto", "Box", "MPM.Elastic", "SPH.Liquid", "x-", "f64"]
    ),
)
_values = st.one_of(
    _scalars,
    st.lists(_scalars, max_size=4),
    st.dictionaries(
        st.sampled_from(["type", "lower", "upper", "center", "radius", "E", "x"]), _scalars, max_size=3
    ),
)
_mutation = st.tuples(
    st.sampled_from(["replace", "replace", "replace", "scale", "delete"]),
    st.integers(min_value=0, max_value=10**6),
    _values,
    st.sampled_from([0.0, -1.0, 1e-12, 1e-3, 0.5, 2.0, 1e3, 1e12, 1e300]),
)


def _mutate(data, op: str, pick: int, value, factor: float) -> None:
    paths = [p for p in _paths(data) if p]
    if not paths:
        return
    path = paths[pick % len(paths)]
    parent = data
    for k in path[:-1]:
        parent = parent[k]
    cur = parent[path[-1]]
    if op == "delete":
        del parent[path[-1]]
    elif op == "scale" and isinstance(cur, (int, float)) and not isinstance(cur, bool):
        parent[path[-1]] = cur * factor
    else:
        parent[path[-1]] = copy.deepcopy(value)


@settings(
    max_examples=120,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(scene=st.sampled_from(SCENES), mutations=st.lists(_mutation, min_size=1, max_size=3))
def test_mutated_shipped_scenes_give_scene_errors_only(scene, mutations):
    base = _base(scene)
    data = copy.deepcopy(base.data)
    for m in mutations:
        _mutate(data, *m)
    loc = Located(data=data, file=base.file, key_pos=dict(base.key_pos), value_pos=dict(base.value_pos))
    try:
        scene_from_located(loc, scene)
    except SceneError as e:
        assert e.lines
        for line in e.lines:
            assert line.startswith(f"{base.file}:"), line


_SNIPPETS = list("[]{}:,-&*!|>'\"#%@`\t\n ?") + [
    "\x00",
    "\u2028",
    "\ufeff",
    "1e400",
    ".nan",
    "<<: *a",
    "&a ",
    "*a",
    "!!str ",
    "!!float ",
    "!!int ",
    "!!python/name:os.system ",
    "~",
    "0x1F",
    "2024-01-01",
]


@settings(max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(
    scene=st.sampled_from(SCENES),
    edits=st.lists(
        st.tuples(st.floats(0, 1), st.integers(0, 5), st.sampled_from(_SNIPPETS)), min_size=1, max_size=4
    ),
)
def test_edited_scene_text_gives_scene_errors_only(scene, edits):
    """The same at the text level: characters of YAML syntax, tags and anchors spliced into a shipped file."""
    from simcli.scene.loader import parse_yaml

    text = scene.read_text()
    for where, cut, snippet in edits:
        i = int(where * len(text))
        text = text[:i] + snippet + text[i + cut :]
    try:
        scene_from_located(parse_yaml(text, str(scene)), scene)
    except SceneError as e:
        assert e.lines
        for line in e.lines:
            assert line.startswith(f"{scene}:") or line.startswith(f"{scene}"), line


def test_the_fuzz_has_scenes():
    assert len(SCENES) > 50
