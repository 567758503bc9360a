"""The order ``file:line:col: ...`` error lines are reported in (a leaf module: the loader and the scene
checks both use it, neither imports the other for it)."""

from __future__ import annotations

import re


def _line_key(line: str):
    m = re.match(r"^(.*?):(\d+):(\d+): ", line)
    return (0, "", 0, 0) if m is None else (1, m.group(1), int(m.group(2)), int(m.group(3)))


def sort_lines(lines: list[str]) -> list[str]:
    """In file order (--set lines first), so a user can fix them top to bottom."""
    return sorted(lines, key=_line_key)
