"""JSON Schema export (``simcli schema``): generated from the same pydantic models."""

from __future__ import annotations

import json
from pathlib import Path

from simcli.scene.models import Scene

SCHEMA_ID = "https://simcli.dev/schemas/scene.schema.json"


def scene_schema() -> dict:
    schema = Scene.model_json_schema(mode="validation")
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["$id"] = SCHEMA_ID
    schema["title"] = "simcli scene"
    return schema


def schema_text() -> str:
    return json.dumps(scene_schema(), indent=2, sort_keys=True) + "\n"


def write_schemas(out_dir: Path) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    p = out_dir / "scene.schema.json"
    p.write_text(schema_text(), encoding="utf-8")
    written.append(p)
    try:  # the sweep schema exists once simcli.sweep is there
        from simcli.sweep.model import sweep_schema_text

        q = out_dir / "sweep.schema.json"
        q.write_text(sweep_schema_text(), encoding="utf-8")
        written.append(q)
    except ImportError:
        pass
    return written
