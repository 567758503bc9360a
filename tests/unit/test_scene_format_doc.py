"""docs/SCENE_FORMAT.md, the user-facing contract, stays in step with the JSON Schema.

Every key of the page's YAML examples that is not marked ``[planned]`` must be accepted by the schema
its block names (``scene.schema.json`` or ``sweep.schema.json``); every key (or ``type`` value) marked
``[planned]`` must still be rejected, so the page never claims what the code does not do and loses the
mark when the feature lands; every key the schema has at the top level and in sim, domain, colliders,
solvers, entities, output and checkpoint must appear in the page; every material type the schema
accepts is in the page's table and every one the table names is accepted unless planned; and every
complete scene on the page validates.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "SCENE_FORMAT.md"
PLANNED = "[planned]"


def _blocks() -> list[tuple[str, str]]:
    """(schema file name, text) of every ```yaml block."""
    out = []
    for text in re.findall(r"```yaml\n(.*?)```", DOC.read_text(), re.S):
        m = re.match(r"# yaml-language-server: \$schema=\.\./schemas/(\S+)\n", text)
        assert m, f"a yaml block of {DOC.name} does not start with its $schema line:\n{text[:200]}"
        out.append((m.group(1), text))
    return out


def _schema(name: str) -> dict:
    return json.loads((ROOT / "schemas" / name).read_text())


class Walker:
    def __init__(self, schema: dict):
        self.root = schema

    def resolve(self, node: dict) -> dict:
        while "$ref" in node:
            node = self.root["$defs"][node["$ref"].rsplit("/", 1)[1]]
        return node

    def alternatives(self, node: dict) -> list[dict]:
        node = self.resolve(node)
        alts = node.get("anyOf") or node.get("oneOf")
        if not alts:
            return [node]
        return [a for alt in alts for a in self.alternatives(alt)]

    @staticmethod
    def _type_values(obj: dict) -> set | None:
        t = obj.get("properties", {}).get("type")
        if t is None:
            return None
        if "const" in t:
            return {t["const"]}
        if "enum" in t:
            return set(t["enum"])
        return None

    def objects(self, node: dict, type_value, strict: bool = False) -> list[dict]:
        """The object alternatives of ``node``; with a ``type`` value, those whose type accepts it."""
        objs = [a for a in self.alternatives(node) if "properties" in a or "additionalProperties" in a]
        if type_value is not None:
            typed = [o for o in objs if self._type_values(o) is not None]
            if typed:
                matching = [o for o in typed if type_value in self._type_values(o)]
                if matching:
                    objs = matching
                elif strict:
                    objs = []
                # else: a planned type value; its siblings are judged against every alternative
        return objs

    def child(self, node: dict, key: str, type_value) -> dict | None:
        for o in self.objects(node, type_value):
            if key in o.get("properties", {}):
                return o["properties"][key]
            extra = o.get("additionalProperties")
            if isinstance(extra, dict):
                names = o.get("propertyNames", {}).get("enum")
                if names is None or key in names:
                    return extra
        return None

    def items(self, node: dict) -> dict | None:
        for a in self.alternatives(node):
            if "items" in a:
                return a["items"]
        return None


def _walk(walker: Walker, schema_node, yaml_node, lines, path, found, problems, planned_paths):
    if isinstance(yaml_node, yaml.SequenceNode):
        item = walker.items(schema_node) if schema_node is not None else None
        for v in yaml_node.value:
            _walk(walker, item, v, lines, path + ["[]"], found, problems, planned_paths)
        return
    if not isinstance(yaml_node, yaml.MappingNode):
        return
    type_value = next(
        (v.value for k, v in yaml_node.value if k.value == "type" and isinstance(v, yaml.ScalarNode)), None
    )
    for k, v in yaml_node.value:
        key = k.value
        line = lines[k.start_mark.line]
        planned = PLANNED in line
        where = f"{DOC.name} block line {k.start_mark.line + 1}: {'.'.join(path + [key])}"
        if key == "type":
            accepted = (
                bool(walker.objects(schema_node, v.value, strict=True)) if schema_node is not None else False
            )
            sub = None
        else:
            sub = walker.child(schema_node, key, type_value) if schema_node is not None else None
            accepted = sub is not None
        if planned:
            planned_paths.append(where)
            if accepted:
                problems.append(f"{where}: marked {PLANNED} but the schema accepts it: remove the mark")
            continue
        if not accepted:
            problems.append(f"{where}: not accepted by the schema: fix the page or mark it {PLANNED}")
            continue
        found.add(".".join(p for p in path + [key] if p != "[]"))
        _walk(walker, sub, v, lines, path + [key], found, problems, planned_paths)


def _check_blocks():
    found: dict[str, set] = {}
    problems: list[str] = []
    planned: list[str] = []
    for name, text in _blocks():
        walker = Walker(_schema(name))
        node = yaml.compose(text)
        _walk(
            walker, walker.root, node, text.splitlines(), [], found.setdefault(name, set()), problems, planned
        )
    return found, problems, planned


def test_every_key_of_the_examples_is_accepted_unless_planned():
    found, problems, planned = _check_blocks()
    assert not problems, "\n".join(problems)
    assert {"scene.schema.json", "sweep.schema.json"} <= set(found)
    # every top-level key of section 5 is implemented now (probes, emitters, sinks: issue 22; rigid_bodies,
    # coupling: issue 20); what stays planned is marked inside them (a key or a type value)


def test_every_schema_key_of_the_main_sections_is_on_the_page():
    found, _, _ = _check_blocks()
    scene, sweep = found["scene.schema.json"], found["sweep.schema.json"]
    w = Walker(_schema("scene.schema.json"))
    missing = []
    top = w.root["properties"]
    for key, node in top.items():
        if key not in scene:
            missing.append(key)
        if key in ("sim", "domain", "output", "checkpoint", "solvers", "entities", "colliders"):
            sub = w.items(node) if key in ("entities", "colliders") else node
            for o in w.objects(sub, None):
                for k in o.get("properties", {}):
                    if f"{key}.{k}" not in scene:
                        missing.append(f"{key}.{k}")
    for k in w.root["$defs"]["Boundary"]["properties"]:
        if f"domain.boundary.{k}" not in scene and not any(
            f"domain.faces.{face}.{k}" in scene for face in ("x-", "x+", "y-", "y+", "z-", "z+")
        ):
            missing.append(f"domain.boundary.{k}")
    for k in _schema("sweep.schema.json")["properties"]:
        if k not in sweep:
            missing.append(f"sweep: {k}")
    assert not missing, f"keys of the schema not shown in {DOC.name}'s examples: {sorted(set(missing))}"


def test_material_table_names_exactly_the_accepted_types():
    from simcli.scene.materials import PLANNED_TYPES, material_type_names

    accepted = set(material_type_names())
    table = [ln for ln in DOC.read_text().splitlines() if ln.startswith("| ")]
    named, planned = set(), set()
    for ln in table:
        for t in re.findall(r"`((?:MPM|FEM|PBD|SPH|SF)\.[A-Za-z]+)`", ln):
            (planned if PLANNED in ln else named).add(t)
    assert named == accepted, f"table {sorted(named)} vs schema {sorted(accepted)}"
    assert planned <= set(PLANNED_TYPES) and not planned & accepted


def test_complete_scenes_on_the_page_validate(tmp_path):
    complete = [t for n, t in _blocks() if n == "scene.schema.json" and "..." not in t and PLANNED not in t]
    assert complete
    files = []
    for i, text in enumerate(complete):
        f = tmp_path / f"scene_{i}.yaml"
        f.write_text(text)
        files.append(str(f))
    r = subprocess.run(
        [sys.executable, "-m", "simcli", "validate", *files], capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0, r.stdout + r.stderr


def _planned_top_level_keys() -> list[str]:
    _, _, planned = _check_blocks()
    keys = [p.rsplit(": ", 1)[1] for p in planned]
    return sorted({k for k in keys if "." not in k})


def test_a_planned_key_is_rejected_by_validate(tmp_path):
    """What the page marks as planned at the top level really is refused, with the key named (not silently
    ignored). Nothing to check once every top-level key is implemented."""
    for planned_key in _planned_top_level_keys():
        f = tmp_path / "s.yaml"
        f.write_text(f"version: 1\n{planned_key}: []\n")
        r = subprocess.run(
            [sys.executable, "-m", "simcli", "validate", str(f)], capture_output=True, text=True, timeout=300
        )
        assert r.returncode == 65 and planned_key in r.stdout + r.stderr


def test_readme_points_at_the_page_inside_the_repository():
    readme = (ROOT / "README.md").read_text()
    assert "docs/SCENE_FORMAT.md" in readme and "../" + "shared" not in readme  # (no folder beside the clone)
