"""JSON Schema export (``simcli schema``): generated from the same pydantic models."""

from __future__ import annotations

import json
from pathlib import Path

from simcli.scene.models import Scene

SCHEMA_ID = "https://simcli.dev/schemas/scene.schema.json"


def model_schema(model, schema_id: str, title: str) -> dict:
    """The JSON Schema (draft 2020-12) of a pydantic model, as editors read it."""
    schema = model.model_json_schema(mode="validation")
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["$id"] = schema_id
    schema["title"] = title
    return schema


def schema_json(schema: dict) -> str:
    return json.dumps(schema, indent=2, sort_keys=True) + "\n"


def scene_schema() -> dict:
    return model_schema(Scene, SCHEMA_ID, "simcli scene")


def schema_text() -> str:
    return schema_json(scene_schema())


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
