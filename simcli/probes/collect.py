"""``simcli sweep collect``'s probe columns: ``probe.<name>[.x|y|z|0|1|2][.final|max|min|mean]`` read from a
run's OUT/probes.csv (default reduction: final; a vector probe without a component: its magnitude).

Every probe of a run is picked up by collect without being named (its four reductions per column); naming
one in ``metrics`` or ``--metric`` adds just that column. NaN samples (a dry point) are skipped by max, min
and mean; final is the last sample taken.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from simcli.probes.recorder import CSV_NAME

REDUCTIONS = ("final", "max", "min", "mean")


_CACHE: dict = {}  # (path, size, mtime) -> columns: collect reads each run's file once for all its columns


def read_csv(path: Path) -> dict[str, list]:
    """Column -> values (None where a cell is empty; rows cut short by a kill are skipped)."""
    st = Path(path).stat()
    key = (str(path), st.st_size, st.st_mtime_ns)
    if key not in _CACHE:
        if len(_CACHE) > 64:
            _CACHE.clear()
        _CACHE[key] = _read(path)
    return _CACHE[key]


def _read(path: Path) -> dict[str, list]:
    with open(path, newline="", encoding="utf-8") as f:
        text = f.read()
    if not text.endswith("\n"):  # the last row was cut short by a kill
        text = text[: text.rfind("\n") + 1]
    rows = list(csv.reader(text.splitlines()))
    if not rows:
        return {}
    header, body = rows[0], [r for r in rows[1:] if len(r) == len(rows[0])]
    out = {}
    for j, col in enumerate(header):
        vals = []
        for r in body:
            c = r[j]
            vals.append(float(c) if c != "" else None)
        out[col] = vals
    return out


def parse(metric: str) -> tuple[str, str | None, str]:
    """'probe.v1.x.max' -> ('v1', 'x', 'max'). Raises ValueError."""
    parts = metric.split(".")
    if len(parts) < 2 or parts[0] != "probe" or not parts[1]:
        raise ValueError(f"'{metric}': expected probe.<name>[.x|y|z][.{'|'.join(REDUCTIONS)}]")
    name, comp, red = parts[1], None, "final"
    for p in parts[2:]:
        if p in REDUCTIONS:
            red = p
        elif p in ("x", "y", "z", "0", "1", "2"):
            comp = "xyz"[int(p)] if p.isdigit() else p
        else:
            raise ValueError(
                f"'{metric}': '{p}' is neither a component (x, y, z) nor one of {', '.join(REDUCTIONS)}"
            )
    return name, comp, red


def _series(cols: dict, name: str, comp: str | None) -> list[float]:
    if comp is not None:
        if f"{name}.{comp}" not in cols:
            raise KeyError(f"probes.csv has no column {name}.{comp}")
        return [v for v in cols[f"{name}.{comp}"] if v is not None]
    if name in cols:
        return [v for v in cols[name] if v is not None]
    parts = [c for c in ("x", "y", "z") if f"{name}.{c}" in cols]
    if not parts:
        raise KeyError(f"probes.csv has no probe {name!r} (has {', '.join(c for c in cols if c != 'time')})")
    rows = zip(*(cols[f"{name}.{c}"] for c in parts))
    return [math.sqrt(sum(x * x for x in r)) for r in rows if all(x is not None for x in r)]


def value(out: Path, metric: str) -> float | None:
    """One probe metric of the run in ``out``; None when the run has no probes.csv. Raises KeyError for a
    probe
    it does not have, ValueError for a malformed metric."""
    name, comp, red = parse(metric)
    path = Path(out) / CSV_NAME
    if not path.is_file():
        return None
    s = _series(read_csv(path), name, comp)
    if not s:
        return None
    if red == "final":
        return float(s[-1])
    a = np.asarray(s, dtype=np.float64)
    if np.all(np.isnan(a)):
        return float("nan")
    return float({"max": np.nanmax, "min": np.nanmin, "mean": np.nanmean}[red](a))


def columns(out_dirs) -> list[str]:
    """probe.<column>.<reduction> for every probe column found in the runs' probes.csv, in file order."""
    found: list[str] = []
    for out in out_dirs:
        path = Path(out) / CSV_NAME
        if not path.is_file():
            continue
        try:
            with open(path, encoding="utf-8") as f:
                header = f.readline().strip().split(",")
        except OSError:
            continue
        for col in header[1:]:
            for red in REDUCTIONS:
                m = f"probe.{col}.{red}"
                if m not in found:
                    found.append(m)
    return found
