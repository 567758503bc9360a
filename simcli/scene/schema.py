"""JSON Schema export (``simcli schema``): generated from the same pydantic models. Writing the schema
files of every file type (scene and sweep) is ``simcli.sweep.schema.write_schemas``."""

from __future__ import annotations

import json

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
