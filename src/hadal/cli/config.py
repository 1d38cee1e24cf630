"""``hadal config``: the default pipeline configuration, or a file or dive directory checked."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer

from hadal.cli._common import console


def config_cmd(
    check: Annotated[Path | None, typer.Option(
        "--check", help="validate instead of printing defaults: a pipeline YAML, or a dive directory (dive.yaml, "
                        "vehicle.yaml, pipeline.yaml and the plan of the stages its data supports)")] = None,
) -> None:
    """Print the default pipeline configuration (commented YAML), or validate a file or dive directory with --check."""
    if check is not None:
        from hadal.settings import load_config

        if check.is_dir():
            _check_dive_dir(check)
            return
        load_config(check)
        console.print(f"{check}: valid")
        return
    print(_default_yaml_cached(), end="")


def _cache_dir() -> Path:
    """``$HADAL_CACHE_DIR``, else ``$XDG_CACHE_HOME/hadal``, else ``~/.cache/hadal``."""
    if os.environ.get("HADAL_CACHE_DIR"):
        return Path(os.environ["HADAL_CACHE_DIR"]).expanduser()
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache").expanduser() / "hadal"


def _default_yaml_cached() -> str:
    """The default configuration (:func:`hadal.settings.default_yaml`), cached per code version.

    The text depends only on hadal's source (:mod:`hadal.settings`), so it is kept under :func:`_cache_dir` keyed
    by :func:`hadal.pipeline.code_digest` (any edit of any hadal source file makes a new key). Best effort: an
    unwritable cache only costs the import."""
    from hadal.pipeline import code_digest

    f = _cache_dir() / f"pipeline-defaults-{code_digest()}.yaml"
    try:
        return f.read_text(encoding="utf-8")
    except (OSError, UnicodeError):
        pass
    from hadal.settings import default_yaml

    text = default_yaml()
    code_digest.cache_clear()
    if code_digest() != f.name[len("pipeline-defaults-"):-len(".yaml")]:  # edited meanwhile: do not cache
        return text
    try:
        f.parent.mkdir(parents=True, exist_ok=True)
        tmp = f.with_name(f".{f.name}.{os.getpid()}")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, f)
    except OSError:
        pass
    return text


def _check_dive_dir(raw_dir: Path) -> None:
    from hadal.ingest.vehicle import load_vehicle_config
    from hadal.pipeline import make_context
    from hadal.stages.plan import check_plan, format_plan

    ctx = make_context(raw_dir, None)
    if ctx.dive.vehicle_config:
        from hadal.dive import resolve_source

        load_vehicle_config(resolve_source(ctx.raw_dir, ctx.dive.vehicle_config))
    missing = [f"{kind}: {e.path}" for kind in ctx.dive.sources.kinds() for e in ctx.dive.sources.files(kind)
               if not _source_exists(ctx.raw_dir, e)]
    if missing:
        from hadal.errors import ConfigError

        raise ConfigError(f"{raw_dir}/dive.yaml lists missing source file(s): {', '.join(missing)}")
    from hadal.pipeline import stage_plan

    plan = stage_plan(ctx)  # also refuses a dive that lists nothing to process
    check_plan(ctx.dive, plan)
    console.print(f"{raw_dir}: valid (dive {ctx.dive_id!r}); plan:")
    print(format_plan(plan))
    from hadal.products import missing_acdd_fields  # discovery metadata the products will lack

    if missing := missing_acdd_fields(ctx.dive):
        print(f"metadata: dive.yaml 'metadata' lacks {', '.join(missing)} (ACDD/IOOS; the products leave them out and "
              "list them in hadal_metadata_missing)")


def _source_exists(raw_dir: Path, entry) -> bool:
    from hadal.dive import resolve_source

    return resolve_source(raw_dir, entry).is_file()
