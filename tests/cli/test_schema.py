"""The committed JSON Schema is generated from the models: a stale one fails."""

from pathlib import Path

from simcli.scene.schema import schema_text

ROOT = Path(__file__).resolve().parents[2]


def test_committed_schema_is_current():
    committed = (ROOT / "schemas" / "scene.schema.json").read_text()
    assert committed == schema_text(), "schemas/scene.schema.json is stale: run `simcli schema -o schemas`"


def test_every_field_has_a_description():
    import json

    schema = json.loads(schema_text())
    missing = []
    for name, d in schema.get("$defs", {}).items():
        for f, prop in d.get("properties", {}).items():
            if f != "type" and "description" not in prop:
                missing.append(f"{name}.{f}")
    assert not missing, missing
