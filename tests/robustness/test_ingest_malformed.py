"""Every malformed input gives a one-line HadalError with nothing published, or published flagged data."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import pandas as pd
import pytest

from hadal.dive import load_dive
from hadal.errors import HadalError
from hadal.products import read_parquet_metadata
from hadal.settings import PipelineConfig
from hadal.stages import StageContext, ingest
from hadal.store import ProductStore

sys.path.insert(0, str(Path(__file__).parents[1] / "malformed"))
from make_corpus import CASES, build_corpus  # noqa: E402


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    return {c.name: (c, d) for c, d in build_corpus(tmp_path_factory.mktemp("corpus"))}


def test_corpus_is_large_enough():
    assert len(CASES) >= 20
    assert len({c.name for c in CASES}) == len(CASES)
    assert sum(c.error is not None for c in CASES) >= 10


@pytest.mark.parametrize("name", [c.name for c in CASES])
def test_malformed_input(corpus, tmp_path, name):
    case, d = corpus[name]
    store = ProductStore(tmp_path / "store")
    dive, raw = load_dive(d)
    ctx = StageContext(dive=dive, raw_dir=raw, store=store,
                       config=PipelineConfig.model_validate({"ingest": {"source": case.source}}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if case.error is not None:
            with pytest.raises(HadalError) as ei:
                ingest.run(ctx)
            msg = str(ei.value)
            assert type(ei.value).__name__ == case.error, msg
            assert "\n" not in msg and len(msg) < 400, msg
            assert pd.Series([msg]).str.contains(case.match, regex=True).iloc[0], msg
            assert not store.has(dive.dive_id, "sensors")
            assert not list((tmp_path / "store").rglob("*.parquet"))  # no half-written product
            return
        res = ingest.run(ctx)
    path = res["sensors"].file("sensors.parquet")
    df = pd.read_parquet(path)
    meta, _ = read_parquet_metadata(path)
    assert case.check is not None and case.check(df, meta), (name, {k: meta.get(k) for k in ("alignment", "mcap", "qc_counts")})
