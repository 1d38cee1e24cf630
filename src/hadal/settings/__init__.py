"""Settings: every stage's options and the resource limits, as typed pydantic models, and the pipeline
configuration made of them (:class:`PipelineConfig`, :func:`load_config`; ``config/pipeline.yaml`` and the
docs' field reference are generated from it: ``hadal config``, ``python -m hadal.schema_docs``).

This package sits below everything else: it imports pydantic, PyYAML, :mod:`hadal.errors` and
:mod:`hadal.yamlfile` only, never a stage, the store or the science; the science and the stages import their
options from here. One module per section: :mod:`hadal.settings.ingest`, ``derive``, ``grid`` (the ``dtm`` and
``laser`` stages), ``suitability``, ``match`` (with the navigation smoother's, :mod:`hadal.settings.navigation`),
``landing``, ``report``, ``resources``; the QARTOD threshold models are :mod:`hadal.settings.qc`.
"""

from hadal.settings.derive import DeriveParams
from hadal.settings.grid import GridParams
from hadal.settings.ingest import IngestParams
from hadal.settings.landing import LandingParams
from hadal.settings.match import MatchParams
from hadal.settings.pipeline import PipelineConfig, default_yaml, load_config
from hadal.settings.report import ReportParams
from hadal.settings.resources import ResourcesParams
from hadal.settings.suitability import SuitabilityParams

__all__ = ["DeriveParams", "GridParams", "IngestParams", "LandingParams", "MatchParams", "PipelineConfig",
           "ReportParams", "ResourcesParams", "SuitabilityParams", "default_yaml", "load_config"]
