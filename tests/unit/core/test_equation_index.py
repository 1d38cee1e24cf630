"""docs/equations.md is the equation index: equation -> function -> test, and the list of citation keys.

Checks, without importing or running anything heavy (static ast checks): every function it lists exists, every test it lists exists (parsed
with ast), every ``[KEY Eq. N]`` citation in ``src/`` docstrings and comments uses a declared key, and no
unkeyed "Eq. N" citation is left there (user-facing string literals are not scanned: they keep their wording).
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
DOC = ROOT / "docs" / "equations.md"
SRC = ROOT / "src"

#: a keyed citation: ``[TERCOM Eq. 17]``, ``[MRF Eqs. 7-13]``, ``[TERCOM\nEq. 17, bias ...]``
KEYED = re.compile(r"\[([A-Za-z][\w-]*)\s+[Ee]qs?\.\s*\(?\d")
#: any equation citation (keyed or not)
CITATION = re.compile(r"\b(?:[Ee]qs?\.|[Ee]quations?)\s*\(?\d")
#: (path relative to src/, start of the citation) of unkeyed citations allowed on purpose, with the reason
ALLOWED_BARE: dict[tuple[str, str], str] = {
    ("hadal/landing/vehicle.py", "Eq. 2 gives"): "class docstring of the pydantic Vehicle model: it is the JSON-schema "
    "description users read (hadal.schema_docs, vehicle.yaml reference), so it keeps its wording",
}


def _doc() -> str:
    return DOC.read_text(encoding="utf-8")


def declared_keys(text: str) -> set[str]:
    section = text.split("## Keys", 1)[1].split("\n## ", 1)[0]
    return set(re.findall(r"^\|\s*`([A-Za-z][\w-]*)`\s*\|", section, flags=re.M))


def listed_functions(text: str) -> list[str]:
    return sorted(set(re.findall(r"`(hadal(?:\.\w+)+)`", text)))


def listed_tests(text: str) -> list[tuple[str, str]]:
    return sorted(set(re.findall(r"`(tests/[\w/]+\.py)::(\w+)`", text)))


def comment_and_docstring_texts(source: str) -> list[tuple[int, str]]:
    """(line, text) of every comment and docstring-like string statement of a Python source."""
    tree = ast.parse(source)
    spans = [(n.lineno, n.end_lineno) for n in ast.walk(tree)
             if isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant) and isinstance(n.value.value, str)]
    out = []
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT or (
                tok.type == tokenize.STRING and any(a <= tok.start[0] <= b for a, b in spans)):
            out.append((tok.start[0], tok.string))
    return out


def yaml_comment_texts(source: str) -> list[tuple[int, str]]:
    return [(i, line.split("#", 1)[1]) for i, line in enumerate(source.splitlines(), 1) if "#" in line]


def bare_citations(text: str) -> list[str]:
    """Citations in ``text`` that are not of the keyed form."""
    stripped = KEYED.sub("[KEYED", text)
    return [stripped[m.start():m.end() + 6] for m in CITATION.finditer(stripped)]


@cache
def src_citation_texts() -> tuple[tuple[str, int, str], ...]:
    """(file, line, text) of the comments and docstrings in src/ that cite an equation."""
    found = []
    for path in sorted(SRC.rglob("*")):
        if path.suffix not in (".py", ".yaml", ".yml") or "__pycache__" in path.parts:
            continue
        source = path.read_text(encoding="utf-8")
        if not CITATION.search(source):
            continue
        texts = comment_and_docstring_texts(source) if path.suffix == ".py" else yaml_comment_texts(source)
        rel = path.relative_to(SRC).as_posix()
        found += [(rel, line, t) for line, t in texts if CITATION.search(t)]
    return tuple(found)


@cache
def _module_names(module: str) -> dict[str, ast.AST] | None:
    """Top-level names of ``src/<module>.py`` (or its package ``__init__``) mapped to their nodes; None: no file."""
    base = SRC.joinpath(*module.split("."))
    path = base.with_suffix(".py") if base.with_suffix(".py").is_file() else base / "__init__.py"
    if not path.is_file():
        return None
    names: dict[str, ast.AST] = {}
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names[node.name] = node
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update({(a.asname or a.name).split(".")[0]: node for a in node.names})
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            for t in node.targets if isinstance(node, ast.Assign) else [node.target]:
                if isinstance(t, ast.Name):
                    names[t.id] = node
    return names


def _resolve(dotted: str) -> str:
    """Resolve ``hadal.pkg.module[.Class][.attr]`` statically (ast, no import: numpy/scipy/xarray would cost
    seconds); returns what it found. The modules themselves are imported by their own test files."""
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        names = _module_names(".".join(parts[:i]))
        if names is None:
            continue
        rest = parts[i:]
        if not rest:
            return "module"
        node = names.get(rest[0])
        assert node is not None, f"{dotted}: {rest[0]!r} is not defined in {'.'.join(parts[:i])}"
        for name in rest[1:]:
            assert isinstance(node, ast.ClassDef), f"{dotted}: {name!r} looked up on a non-class"
            members = {n.name: n for n in node.body if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef,
                                                                       ast.ClassDef))}
            members.update({t.target.id: t for t in node.body
                            if isinstance(t, ast.AnnAssign) and isinstance(t.target, ast.Name)})
            node = members.get(name)
            assert node is not None, f"{dotted}: {name!r} is not a member"
        return type(node).__name__
    raise AssertionError(f"{dotted}: no such module under src/")


@cache
def _test_names(path: str) -> frozenset[str]:
    tree = ast.parse((ROOT / path).read_text(encoding="utf-8"))
    return frozenset(n.name for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)))


def test_doc_declares_keys_and_lists_functions_and_tests():
    text = _doc()
    assert {"TERCOM", "MRF", "Landing"} <= declared_keys(text)
    assert len(listed_functions(text)) > 20 and len(listed_tests(text)) > 30


@pytest.mark.parametrize("dotted", listed_functions(_doc()))
def test_listed_function_exists(dotted):
    assert _resolve(dotted) in ("module", "FunctionDef", "ClassDef", "ImportFrom", "Assign"), dotted


def test_listed_tests_exist():
    missing = [f"{p}::{n}" for p, n in listed_tests(_doc())
               if not (ROOT / p).is_file() or n not in _test_names(p)]
    assert not missing, f"docs/equations.md lists tests that do not exist: {missing}"


def test_src_citations_use_declared_keys():
    keys = declared_keys(_doc())
    bad = [f"{f}:{line}: [{k} ..." for f, line, t in src_citation_texts() for k in KEYED.findall(t) if k not in keys]
    assert not bad, f"citation keys not declared in docs/equations.md: {bad}"


def test_no_unkeyed_citation_in_src():
    bad = [f"{f}:{line}: {b!r}" for f, line, t in src_citation_texts() for b in bare_citations(t)
           if not any(f == af and b.startswith(ab) for af, ab in ALLOWED_BARE)]
    assert not bad, ("unkeyed equation citations in src/ (write [TERCOM Eq. N], [MRF Eq. N], [Landing Eq. N], ..."
                     f" and declare new keys in docs/equations.md): {bad}")
    assert len(src_citation_texts()) > 50  # the scan does see the keyed citations


def test_scanner_catches_unkeyed_and_ignores_string_literals():
    source = ('"""Module [TERCOM Eq. 17] and [MRF\nEqs. 7-13]."""\n'
              'X = f("Eq. 14")  # gravity, Eq. (14)\n'
              'def g():\n    """R_max (Eqs. 13-14)."""\n')
    texts = comment_and_docstring_texts(source)
    bare = [b for _, t in texts for b in bare_citations(t)]
    assert len(bare) == 2 and bare[0].startswith("Eq. (14)") and bare[1].startswith("Eqs. 13")
    assert [k for _, t in texts for k in KEYED.findall(t)] == ["TERCOM", "MRF"]
