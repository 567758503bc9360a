"""The scene reader's YAML layer: YAML text to plain data with the line and column of every key and value
(:class:`Located`), within the reader's limits (docs/LIMITS.md). No scene model here: a leaf module that
``loader.py`` (scene and sweep files) and ``overrides.py`` (``--set`` values) both read with."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import yaml

from simcli.errors import SceneError

Path_ = tuple  # a key path: str keys and int list indices


@dataclass
class Located:
    """Plain YAML data plus the source position of every key and value."""

    data: Any
    file: str
    key_pos: dict[Path_, tuple[int, int]] = field(default_factory=dict)  # 1-based line, column of a key
    value_pos: dict[Path_, tuple[int, int]] = field(default_factory=dict)
    override_src: dict[Path_, str] = field(default_factory=dict)  # path -> "--set k=v" text

    def where(self, path: Path_, prefer_key: bool = False) -> str:
        """``file:line:col`` of the deepest known node on ``path``."""
        p = tuple(path)
        while True:
            if p in self.override_src:
                return self.override_src[p]
            table = (self.key_pos, self.value_pos) if prefer_key else (self.value_pos, self.key_pos)
            for t in table:
                if p in t:
                    line, col = t[p]
                    return f"{self.file}:{line}:{col}"
            if not p:
                return f"{self.file}:1:1"
            p = p[:-1]


def _mark(node) -> tuple[int, int]:
    return node.start_mark.line + 1, node.start_mark.column + 1


# The YAML reader's limits (docs/LIMITS.md): a scene is a few hundred nodes; these stop a "billion laughs"
# (aliases of aliases expanding exponentially), a recursive alias and a 50,000-deep nesting before they cost
# memory, time or Python's stack.
MAX_DEPTH = 64  # nesting levels of mappings and lists
MAX_NODES = 100_000  # nodes after every alias is expanded (the shipped scenes have < 2,000)
MAX_FILE_BYTES = 4 * 2**20  # a scene or sweep file (the largest shipped one is a few KB)
# tags the loader constructs; any other (!!python/object/new:dict, !!binary, !!set, !custom) is refused
_ALLOWED_TAGS = {
    "tag:yaml.org,2002:" + t for t in ("map", "seq", "str", "int", "float", "bool", "null", "merge")
}


def _where_node(loc_file: str, node) -> str:
    line, col = _mark(node)
    return f"{loc_file}:{line}:{col}"


def _check_tree(node, file: str) -> None:
    """Refuse unknown tags, recursive aliases and an expanded size over MAX_NODES, in time linear in the
    file (sizes are memoised per node, so a billion laughs is measured without being expanded)."""
    sizes: dict[int, int] = {}
    active: set[int] = set()

    def size(n) -> int:
        k = id(n)
        if k in sizes:
            return sizes[k]
        if k in active:
            raise SceneError(
                [
                    f"{_where_node(file, n)}: malformed YAML: a recursive alias (an anchor used inside "
                    "itself); write the value out"
                ]
            )
        if n.tag not in _ALLOWED_TAGS:
            raise SceneError(
                [
                    f"{_where_node(file, n)}: YAML tag '{n.tag}' is not supported (a scene holds plain "
                    "mappings, lists, strings, numbers, booleans and null); remove the tag"
                ]
            )
        active.add(k)
        total = 1
        if isinstance(n, yaml.MappingNode):
            for kn, vn in n.value:
                total += size(kn) + size(vn)
                if total > MAX_NODES:
                    break
        elif isinstance(n, yaml.SequenceNode):
            for it in n.value:
                total += size(it)
                if total > MAX_NODES:
                    break
        active.discard(k)
        sizes[k] = total
        if total > MAX_NODES:
            raise SceneError(
                [
                    f"{_where_node(file, n)}: YAML too large: more than {MAX_NODES:,} values once its "
                    "aliases (*name) are expanded (a scene has a few hundred); remove the nested aliases"
                ]
            )
        return total

    size(node)


def _construct(loader, node, file: str) -> Any:
    """A scalar's value; an explicit tag that does not fit it (``!!float abc``, ``!!int 1.5``) is an error at
    its place, not a ValueError from PyYAML's constructor."""
    try:
        return loader.construct_object(node, deep=True)
    except (ValueError, TypeError, OverflowError, IndexError, KeyError) as e:  # PyYAML raises these
        tag = str(node.tag).replace("tag:yaml.org,2002:", "!!")
        raise SceneError([f"{_where_node(file, node)}: cannot read {node.value!r} as {tag}: {e}"]) from None


def _walk(loader, node, path: Path_, loc: Located, errors: list[str]) -> Any:
    if isinstance(node, yaml.MappingNode):
        loader.flatten_mapping(node)
        out: dict = {}
        for knode, vnode in node.value:
            key = _construct(loader, knode, loc.file)
            if not isinstance(key, (str, int, float, bool)) or key is None:
                errors.append(
                    f"{loc.file}:{_mark(knode)[0]}:{_mark(knode)[1]}: {_dotted(path)}: keys must be "
                    f"plain names (found {type(key).__name__})"
                )
                continue
            if key in out:
                line, col = _mark(knode)
                errors.append(
                    f"{loc.file}:{line}:{col}: {_dotted(path + (key,))}: duplicate key (the last one "
                    f"would silently win; remove one)"
                )
            loc.key_pos[path + (key,)] = _mark(knode)
            loc.value_pos[path + (key,)] = _mark(vnode)
            out[key] = _walk(loader, vnode, path + (key,), loc, errors)
        return out
    if isinstance(node, yaml.SequenceNode):
        items = []
        for i, item in enumerate(node.value):
            loc.value_pos[path + (i,)] = _mark(item)
            loc.key_pos.setdefault(path + (i,), _mark(item))
            items.append(_walk(loader, item, path + (i,), loc, errors))
        return items
    return _construct(loader, node, loc.file)


class _Loader(yaml.SafeLoader):
    """SafeLoader with YAML 1.2 floats (PyYAML, YAML 1.1, reads 1e5 or -1e-3 as strings), no implicit
    dates (2024-01-01 stays a string) and a nesting depth limit (the composer recurses per level)."""

    _depth = 0

    def compose_node(self, parent, index):
        self._depth += 1
        try:
            if self._depth > MAX_DEPTH:
                mark = self.peek_event().start_mark
                raise yaml.MarkedYAMLError(
                    problem=f"nested more than {MAX_DEPTH} levels deep (a scene needs fewer than 10)",
                    problem_mark=mark,
                )
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(
        r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
    |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
    |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
    |[-+]?\.(?:inf|Inf|INF)
    |\.(?:nan|NaN|NAN))$""",
        re.VERBOSE,
    ),
    list("-+0123456789."),
)
_Loader.yaml_implicit_resolvers = {
    k: [r for r in v if r[0] != "tag:yaml.org,2002:timestamp"]
    for k, v in _Loader.yaml_implicit_resolvers.items()
}


def parse_yaml_any(text: str, file: str) -> Located:
    """Parse YAML text of any shape (a ``--set`` value), keeping positions, within the reader's limits
    (MAX_DEPTH, MAX_NODES, plain tags only). Raises SceneError for malformed or refused YAML; an empty
    document gives None."""
    loc = Located(data=None, file=file)
    errors: list[str] = []
    try:
        loader = _Loader(text)
        try:
            node = loader.get_single_node()
            if node is not None:
                _check_tree(node, file)
                loc.data = _walk(loader, node, (), loc, errors)
        finally:
            loader.dispose()
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        line, col = (mark.line + 1, mark.column + 1) if mark else (1, 1)
        problem = e.problem or "malformed YAML"
        ctx = f" ({e.context})" if e.context else ""
        raise SceneError([f"{file}:{line}:{col}: malformed YAML: {problem}{ctx}"]) from None
    except yaml.YAMLError as e:
        raise SceneError([f"{file}:1:1: malformed YAML: {e}"]) from None
    except RecursionError:  # a guard of last resort: MAX_DEPTH stops the composer first
        raise SceneError([f"{file}:1:1: malformed YAML: nested too deeply"]) from None
    if errors:
        raise SceneError(errors)
    return loc


def _dotted(path) -> str:
    return ".".join(str(p) for p in path) if path else "(top level)"
