"""Put the repository's ``tests/`` folder on ``sys.path``: the benches use the tests' fixture factories
(``factories``, ``landing_fixtures``), which are not shipped in the wheel. Import it before them."""

import sys
from pathlib import Path

_TESTS = str(Path(__file__).resolve().parents[1] / "tests")
if _TESTS not in sys.path:
    sys.path.insert(0, _TESTS)
