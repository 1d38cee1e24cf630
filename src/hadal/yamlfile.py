"""Reading hadal's YAML files (dive.yaml, vehicle.yaml, pipeline.yaml) with one-line errors for every way a
user's file can be wrong: missing, a directory or FIFO, unreadable, not UTF-8, not YAML, not a mapping, too big.

Parsing is bounded before anything is built (:func:`check_yaml_bounds`, :func:`load_json_bounded`): a size cap
(:data:`MAX_CONFIG_BYTES`), a nesting-depth cap (:data:`MAX_DEPTH`), a cap on the number of nodes *after* alias
expansion (:data:`MAX_NODES`: "billion laughs" documents are refused by counting, never expanded) and a cap on one
scalar's length (:data:`MAX_SCALAR_CHARS`; integers also within Python's digit limit), each a one-line error.
"""

from __future__ import annotations

import json
import re
import stat
import sys
from pathlib import Path
from typing import Any

import yaml

from hadal.errors import ConfigError

#: largest YAML configuration file read (a dive.yaml listing thousands of sources is ~1 MB)
MAX_CONFIG_BYTES = 4 << 20
#: deepest nesting of mappings/sequences (hadal's files nest 4-5 levels)
MAX_DEPTH = 64
#: most nodes in a document counted with every alias expanded (a dive.yaml listing 10 000 files is ~50 000)
MAX_NODES = 1_000_000
#: longest single scalar (free-text notes included)
MAX_SCALAR_CHARS = 256 * 1024


class YAMLLimitError(yaml.YAMLError):
    """A document exceeds one of the parsing bounds (size, depth, expanded nodes, scalar length)."""


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


def check_yaml_bounds(text: str) -> None:
    """Raise :class:`YAMLLimitError` when ``text`` exceeds :data:`MAX_CONFIG_BYTES`, :data:`MAX_DEPTH`,
    :data:`MAX_NODES` (aliases expanded) or :data:`MAX_SCALAR_CHARS`.

    One pass over the parser's events (libyaml's when available), building nothing: an alias adds the node
    count of its anchor's subtree, so a billion-laughs document is refused after reading its few lines, and the
    depth is counted before the (recursive) composer would see it. Syntax errors are left to the loader."""
    if len(text) > MAX_CONFIG_BYTES:
        raise YAMLLimitError(f"{len(text) / 2**20:.1f} MiB is more than the {MAX_CONFIG_BYTES >> 20} MiB a "
                             "configuration file may have")
    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)(text)
    sizes: dict[str, int] = {}  # anchor -> expanded node count of its subtree
    stack: list[list[Any]] = [[None, 0]]  # [anchor, nodes so far] per open collection
    total = 0
    try:
        while (ev := loader.get_event()) is not None:
            if isinstance(ev, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
                stack.append([ev.anchor, 0])
                if len(stack) - 1 > MAX_DEPTH:
                    raise YAMLLimitError(f"nested more than {MAX_DEPTH} levels deep (line {ev.start_mark.line + 1})")
                continue
            if isinstance(ev, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
                anchor, n = stack.pop()
                n += 1
            elif isinstance(ev, yaml.ScalarEvent):
                if len(ev.value) > MAX_SCALAR_CHARS:
                    raise YAMLLimitError(f"a value of {len(ev.value)} characters at line {ev.start_mark.line + 1} "
                                         f"(at most {MAX_SCALAR_CHARS} are read)")
                anchor, n = ev.anchor, 1
            elif isinstance(ev, yaml.AliasEvent):
                anchor, n = None, sizes.get(ev.anchor, 1)
                total += n
            else:
                continue
            if anchor is not None:
                sizes[anchor] = n
            stack[-1][1] += n
            if stack[-1][1] > MAX_NODES or total > MAX_NODES:
                raise YAMLLimitError(f"more than {MAX_NODES} values once its aliases (*name) are expanded "
                                     "(an alias bomb?)")
    except YAMLLimitError:
        raise
    except yaml.YAMLError as exc:
        if "nesting depth" in str(exc):  # libyaml's own cap (1000), met while it scans ahead
            raise YAMLLimitError(f"nested more than {MAX_DEPTH} levels deep") from None
        return  # not valid YAML: the loader reports it in its own words
    finally:
        loader.dispose()


def safe_load_unique(text: str) -> Any:
    """``yaml.safe_load`` that raises :class:`DuplicateKeyError` for a key repeated in one mapping, and
    :class:`YAMLLimitError` for a document beyond the parsing bounds (:func:`check_yaml_bounds`)."""
    check_yaml_bounds(text)
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 - a SafeLoader subclass
    except RecursionError:
        raise YAMLLimitError(f"nested more than {MAX_DEPTH} levels deep") from None
    except ValueError as exc:  # e.g. an integer beyond Python's 4300-digit limit
        if "integer string conversion" in str(exc):
            raise YAMLLimitError(f"an integer with more than {sys.get_int_max_str_digits()} digits") from None
        raise YAMLLimitError(str(exc).splitlines()[0] if str(exc) else type(exc).__name__) from None


def read_config_text(path: str | Path, what: str) -> str:
    """The UTF-8 text of a user's configuration file, or a one-line :class:`ConfigError` when it is missing, not a
    regular file, larger than :data:`MAX_CONFIG_BYTES` (checked before and while reading: a growing file cannot
    make it read more) or not UTF-8."""
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
    too_big = (f"{what} {p} is larger than {MAX_CONFIG_BYTES >> 20} MiB; refusing to parse it (a configuration "
               "file is a few kB)")
    if st.st_size > MAX_CONFIG_BYTES:
        raise ConfigError(too_big)
    try:
        with open(p, "rb") as fh:
            raw = fh.read(MAX_CONFIG_BYTES + 1)
    except OSError as exc:
        raise ConfigError(f"{what} {p}: cannot be read ({exc.strerror or exc})") from None
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError(too_big)
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{p}: not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start}); save the "
                          "file as UTF-8") from None


def parse_yaml_text(text: str, p: str | Path) -> Any:
    """:func:`safe_load_unique` with its errors as one-line :class:`ConfigError` naming ``p``."""
    try:
        return safe_load_unique(text)
    except (DuplicateKeyError, YAMLLimitError) as exc:
        raise ConfigError(f"{p}: {'refusing to parse it: ' if isinstance(exc, YAMLLimitError) else ''}{exc}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{p}: not valid YAML ({str(exc).splitlines()[0]})") from None


def load_yaml_mapping(path: str | Path, what: str, *, empty_ok: bool = False) -> dict[str, Any]:
    """The top-level mapping of a YAML file, or a one-line :class:`ConfigError` naming ``path`` and ``what``
    it should be (e.g. ``"dive description"``). ``empty_ok``: an empty file is ``{}``. Bounded: size, depth,
    aliases and scalars (:func:`read_config_text`, :func:`check_yaml_bounds`)."""
    p = Path(path)
    data = parse_yaml_text(read_config_text(p, what), p)
    if data is None and empty_ok:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: expected a mapping at the top level of the {what}")
    return data


def load_json_bounded(data: bytes | str, *, max_bytes: int = MAX_CONFIG_BYTES, max_depth: int = MAX_DEPTH) -> Any:
    """``json.loads`` with a size cap and a nesting-depth cap checked before parsing (a deeply nested document
    would otherwise end in a ``RecursionError``); a ``ValueError`` with a one-line message when out of bounds."""
    if len(data) > max_bytes:
        raise ValueError(f"{len(data)} bytes, more than the {max_bytes} read")
    text = data.decode("utf-8") if isinstance(data, bytes) else data
    if _json_depth(text) > max_depth:
        raise ValueError(f"JSON nested more than {max_depth} levels deep")
    return json.loads(text)


_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"')
_BRACKETS = re.compile(r"[\[\]{}]")


def _json_depth(text: str) -> int:
    """Deepest bracket nesting of a JSON text, strings skipped (linear, no recursion)."""
    depth = deepest = 0
    for m in _BRACKETS.finditer(_JSON_STRING.sub("", text)):
        if m.group() in "[{":
            depth += 1
            deepest = max(deepest, depth)
        else:
            depth -= 1
    return deepest
