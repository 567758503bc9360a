"""Where scene text comes from, and where each of its keys was (no Taichi; a leaf of simcli.scene):
the YAML 1.2 loader (also used by ``--set`` overrides), ``Located`` (data plus the file:line:col of
every key), ``LoadedScene`` (a validated scene and its source) and the order error lines are
reported in. ``simcli.scene.loader`` builds them; ``checks`` and ``overrides`` use them."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from simcli.scene.models import Scene

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


class YAML12Loader(yaml.SafeLoader):
    """SafeLoader with YAML 1.2 floats: PyYAML (YAML 1.1) reads 1e5 or -1e-3 as strings."""


YAML12Loader.add_implicit_resolver(
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


def _line_key(line: str):
    m = re.match(r"^(.*?):(\d+):(\d+): ", line)
    return (0, "", 0, 0) if m is None else (1, m.group(1), int(m.group(2)), int(m.group(3)))


def sort_lines(lines: list[str]) -> list[str]:
    """In file order (--set lines first), so a user can fix them top to bottom."""
    return sorted(lines, key=_line_key)


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
