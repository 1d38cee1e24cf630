"""Reading hadal's YAML files (dive.yaml, vehicle.yaml, pipeline.yaml) with one-line errors for every way a
user's file can be wrong: missing, a directory or FIFO, unreadable, not UTF-8, not YAML, not a mapping."""

from __future__ import annotations

import stat
from pathlib import Path
from typing import Any

import yaml

from hadal.errors import ConfigError


class DuplicateKeyError(yaml.YAMLError):
    """A mapping (at any depth) names the same key twice; plain YAML loaders keep the last one silently."""


class _UniqueKeyLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that refuses a key repeated within one mapping, at any depth (YAML 1.2 requires
    keys to be unique; PyYAML keeps the last). Merge keys (``<<``) are still resolved as usual."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: dict[Any, int] = {}
        for key_node, _value_node in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=True)
            try:
                first = seen.get(key)
            except TypeError:  # unhashable key: the base constructor reports it
                continue
            line = key_node.start_mark.line + 1
            if first is not None:
                raise DuplicateKeyError(f"duplicate key {key!r} at lines {first} and {line} (YAML would keep "
                                        "only the last one silently; remove or rename one)")
            seen[key] = line
        return super().construct_mapping(node, deep=deep)


def safe_load_unique(text: str) -> Any:
    """``yaml.safe_load`` that raises :class:`DuplicateKeyError` for a key repeated in one mapping."""
    return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass


def load_yaml_mapping(path: str | Path, what: str, *, empty_ok: bool = False) -> dict[str, Any]:
    """The top-level mapping of a YAML file, or a one-line :class:`ConfigError` naming ``path`` and ``what``
    it should be (e.g. ``"dive description"``). ``empty_ok``: an empty file is ``{}``."""
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        raise ConfigError(f"{what} {p} does not exist") from None
    except OSError as exc:  # symlink loop, permission on a parent, ...
        raise ConfigError(f"{what} {p}: cannot be opened ({exc.strerror or exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise ConfigError(f"{what} {p} is a directory, not a YAML file")
    if not stat.S_ISREG(st.st_mode):
        raise ConfigError(f"{what} {p} is not a regular file (a FIFO, socket or device)")
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{what} {p}: cannot be read ({exc.strerror or exc})") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start}); save the "
                          "file as UTF-8") from None
    try:
        data = safe_load_unique(text)
    except DuplicateKeyError as exc:
        raise ConfigError(f"{p}: {exc}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{p}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if data is None and empty_ok:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: expected a mapping at the top level of the {what}")
    return data
