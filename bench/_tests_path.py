"""Put the repository's ``tests/`` folder on ``sys.path``: the benches use the tests' fixture factories
(``factories``, ``landing_fixtures``), which are not shipped in the wheel, and a test module's helpers (its folder
appended, as ``tests/conftest.py`` does). Import it before them."""

import sys
from pathlib import Path

_TESTS = str(Path(__file__).resolve().parents[1] / "tests")
if _TESTS not in sys.path:
    sys.path.insert(0, _TESTS)
for _folder in sorted({str(t.parent) for t in Path(_TESTS).glob("*/**/test_*.py")}):
    if _folder not in sys.path:
        sys.path.append(_folder)
