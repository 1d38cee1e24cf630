"""JSON Schemas and field reference of the configuration files, generated from their pydantic models.

``hadal schema dive|vehicle|pipeline`` prints :func:`json_schema`; ``docs/dive-directory.md`` embeds the field
tables of :func:`field_reference` (``python -m hadal.schema_docs`` rewrites the generated part, a test checks it
is current). Editors validate ``dive.yaml`` with the schema, e.g. with a first line
``# yaml-language-server: $schema=dive.schema.json``.
"""

from __future__ import annotations

import json
from typing import Any

from pydantic import BaseModel

from hadal.errors import ConfigError

BEGIN = "<!-- BEGIN GENERATED FIELD REFERENCE (python -m hadal.schema_docs) -->"
END = "<!-- END GENERATED FIELD REFERENCE -->"


def models() -> dict[str, type[BaseModel]]:
    from hadal.dive import Dive
    from hadal.ingest.vehicle import VehicleConfig
    from hadal.settings import PipelineConfig

    return {"dive": Dive, "vehicle": VehicleConfig, "pipeline": PipelineConfig}


def json_schema(what: str) -> dict[str, Any]:
    """The JSON Schema (draft 2020-12, pydantic's) of ``dive``, ``vehicle`` or ``pipeline`` YAML files."""
    m = models()
    if what not in m:
        raise ConfigError(f"unknown schema {what!r}; choose one of {', '.join(m)}")
    s = m[what].model_json_schema()
    s["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    s.setdefault("title", f"hadal {what}.yaml")
    return s


def _type_text(prop: dict[str, Any], defs: dict[str, Any]) -> str:
    if "$ref" in prop:
        return f"`{prop['$ref'].rsplit('/', 1)[-1]}`"
    if "anyOf" in prop:
        return " or ".join(_type_text(p, defs) for p in prop["anyOf"])
    if "enum" in prop:
        return " / ".join(f"`{v}`" for v in prop["enum"])
    if "const" in prop:
        return f"`{prop['const']}`"
    t = prop.get("type", "any")
    if t == "array":
        return f"list of {_type_text(prop.get('items', {}), defs)}"
    if t == "object":
        add = prop.get("additionalProperties")
        return f"mapping of name to {_type_text(add, defs)}" if isinstance(add, dict) else "mapping"
    bounds = [f"{k} {prop[k]}" for k in ("minimum", "exclusiveMinimum", "maximum", "exclusiveMaximum", "minLength")
              if k in prop]
    return t + (f" ({', '.join(bounds)})" if bounds else "")


def _table(name: str, schema: dict[str, Any], defs: dict[str, Any]) -> list[str]:
    req = set(schema.get("required", []))
    lines = [f"#### `{name}`", ""]
    if schema.get("description"):
        lines += [" ".join(schema["description"].split()), ""]
    lines += ["| field | type | required | default | description |", "|---|---|---|---|---|"]
    for key, prop in schema.get("properties", {}).items():
        default = json.dumps(prop["default"]) if "default" in prop else ""
        if len(default) > 40:
            default = "(see `hadal config`)" if name == "PipelineConfig" else default[:37] + "..."
        desc = " ".join(str(prop.get("description", "")).split()).replace("|", "\\|")
        lines.append(f"| `{key}` | {_type_text(prop, defs)} | {'yes' if key in req else ''} | {default} | {desc} |")
    return lines + [""]


def field_reference(which: tuple[str, ...] = ("dive", "vehicle")) -> str:
    """Markdown tables of every field of the models (and the models they use), from their JSON Schemas."""
    out: list[str] = []
    for what in which:
        s = json_schema(what)
        defs = s.get("$defs", {})
        out.append(f"### {what}.yaml")
        out.append("")
        out += _table(s.get("title", what), s, defs)
        for dname, d in defs.items():
            out += _table(dname, d, defs)
    return "\n".join(out).rstrip() + "\n"


def render_doc(text: str) -> str:
    """``text`` (docs/dive-directory.md) with its generated section replaced by the current reference."""
    if BEGIN not in text or END not in text:
        raise ConfigError("docs/dive-directory.md has no generated-reference markers")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n\n{field_reference()}\n{END}{tail}"


if __name__ == "__main__":  # rewrite the generated part of docs/dive-directory.md
    from pathlib import Path

    doc = Path(__file__).resolve().parents[2] / "docs" / "dive-directory.md"
    doc.write_text(render_doc(doc.read_text(encoding="utf-8")), encoding="utf-8")
    print(f"updated {doc}")
