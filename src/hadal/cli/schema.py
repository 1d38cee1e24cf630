"""``hadal schema``: the JSON Schema of a configuration file."""

from __future__ import annotations

import json
from typing import Annotated

import typer


def schema(
    what: Annotated[str, typer.Argument(help="dive, vehicle or pipeline")],
) -> None:
    """Print the JSON Schema of dive.yaml, vehicle.yaml or pipeline.yaml (for editors' YAML validation)."""
    from hadal.schema_docs import json_schema

    print(json.dumps(json_schema(what), indent=2))
