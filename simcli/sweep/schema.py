"""The JSON Schema files of every file type simcli reads (``simcli schema -o DIR``): scene files
(``simcli.scene.schema``) and sweep files (``simcli.sweep.model``). Here, above both, so that the
scene layer never imports the sweep layer."""

from __future__ import annotations

from pathlib import Path

from simcli.scene.schema import schema_text
from simcli.sweep.model import sweep_schema_text


def write_schemas(out_dir: Path) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    p = out_dir / "scene.schema.json"
    p.write_text(schema_text(), encoding="utf-8")
    written.append(p)
    q = out_dir / "sweep.schema.json"
    q.write_text(sweep_schema_text(), encoding="utf-8")
    written.append(q)
    return written
