"""Pipeline configuration: defaults file in sync with the models, merging, clear errors."""

from pathlib import Path

import pytest
import yaml

from hadal.errors import ConfigError
from hadal.settings import PipelineConfig, default_yaml, load_config

REPO = Path(__file__).resolve().parents[3]


def test_committed_defaults_match_models():
    """config/pipeline.yaml is the commented dump of the defaults (regenerate: hadal config > config/pipeline.yaml)."""
    committed = (REPO / "config" / "pipeline.yaml").read_text()
    assert committed == default_yaml()
    assert load_config(REPO / "config" / "pipeline.yaml") == PipelineConfig()


def test_default_yaml_round_trips():
    assert PipelineConfig.model_validate(yaml.safe_load(default_yaml()) or {}) == PipelineConfig()


def test_later_files_override_earlier(tmp_path):
    a, b = tmp_path / "a.yaml", tmp_path / "b.yaml"
    a.write_text("{}\n")
    b.write_text("{}\n")
    assert load_config(a, None, b) == PipelineConfig()


@pytest.mark.parametrize("text,frag", [("[1, 2]", "mapping"), ("ingest: {no_such_option: 3}", "no_such_option"),
                                       ("a: [", "not valid YAML")])
def test_bad_config_is_one_clear_error(tmp_path, text, frag):
    p = tmp_path / "c.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError, match=frag):
        load_config(p)


def test_library_callers_catch_hadal_errors_as_value_errors(tmp_path):
    """Issue 20 item 5: bad values raise what numpy/xarray callers already catch (ValueError), with the same
    one-line message, while the CLI still tells them apart from bugs (HadalError)."""
    from hadal.errors import HadalError
    from hadal.matching.fix import resample_along_track

    p = tmp_path / "c.yaml"
    p.write_text("ingest: {no_such_option: 3}")
    with pytest.raises(ValueError, match="no_such_option") as exc:
        load_config(p)
    assert isinstance(exc.value, HadalError)
    with pytest.raises(ValueError, match="spacing must be > 0") as exc:  # an InputError from the science library
        resample_along_track([0.0, 1.0], [0.0, 1.0], [5.0, 5.0], spacing_m=0.0)
    assert isinstance(exc.value, HadalError)
