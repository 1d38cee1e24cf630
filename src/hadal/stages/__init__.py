"""Pipeline stages: Prefect-free functions that read inputs from the store and publish new versions.

Each stage module ``hadal.stages.<name>`` declares one :class:`Stage` record, ``STAGE``: its name, the products it
publishes, its :class:`StageInputs` (raw source kinds and upstream products, from which :mod:`hadal.stages.plan` decides
whether it runs on a dive), its options model (``hadal.settings``), its ``run(ctx) -> {product: version}`` and the
optional hooks (a content check ``skip_reason``, ``planned_products``, ``raw_files``, a shared configuration
``section`` with the ``param_fields`` it uses, ``warm_imports``, ``process``). :mod:`hadal.stages.graph` collects
them in :data:`~hadal.stages.graph.STAGES` and derives, once, the graph (who waits for whom), the producer of each
product and every product; the plan, the cache fingerprint, the flow and the in-process runner use it.

The Prefect tasks in ``tasks/`` are thin wrappers around ``run``; the flow in ``flows/`` runs each as soon as the
stages it reads from are done. Data flows one way: raw → ingest → derive; raw → dtm → suitability → match;
raw → laser → landing; all → report. ``grid`` names the two gridding stages together (:data:`STAGE_GROUPS`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hadal.errors import StageError
from hadal.steps import NullProgress, Progress

if TYPE_CHECKING:
    from pydantic import BaseModel

    from hadal.dive import Dive
    from hadal.settings import PipelineConfig
    from hadal.store import ProductStore, ProductVersion


#: Stages in execution order (also the flow's priority among ready stages). Only stages whose module defines
#: ``run`` are part of the pipeline.
STAGE_ORDER: tuple[str, ...] = ("ingest", "derive", "dtm", "laser", "suitability", "match", "profile", "landing",
                                 "report")

#: Names that stand for several stages wherever a stage is named (``hadal stage grid``, ``run_stage("grid")``):
#: ``grid`` is the DTM and the laser grids, one stage before they were split so that each runs (and re-runs)
#: on its own inputs and parameters.
STAGE_GROUPS: dict[str, tuple[str, ...]] = {"grid": ("dtm", "laser")}


@dataclass(frozen=True)
class StageInputs:
    """What a stage needs to run on a dive (declared next to its ``Params``; used by :mod:`hadal.stages.plan`).

    * ``raw_any``: at least one of these ``dive.yaml`` source kinds must list a file (empty: no raw input);
    * ``upstream``: products that must be published by an earlier stage (or already be in the store);
    * ``optional_upstream``: products it uses when they exist (``report`` reads whatever is there);
    * ``product_sources``: which raw kinds make which of its products (``ingest``: ``casts`` only from
      Sea-Bird ``cnv`` files); products not named here are made whenever it runs;
    * ``always``: run even without any input (``report``: it says what was skipped and why);
    * ``needs_launch``: the dive's launch position is required (the plan is refused, naming the stage);
    * ``reads_raw``: the stage reads the ``raw_any`` files themselves (ingest, dtm, laser), so they are part of its
      cache fingerprint (``hadal.tasks.stage``); ``match`` only needs a vehicle log to exist;
    * ``frame_for``: products whose making needs the dive's map frame (``map_frame`` or ``launch``);
    * ``optional_products``: products made only when the data calls for them (not promised by the plan).
    """

    raw_any: tuple[str, ...] = ()
    upstream: tuple[str, ...] = ()
    optional_upstream: tuple[str, ...] = ()
    product_sources: dict[str, tuple[str, ...]] = field(default_factory=dict)
    always: bool = False
    needs_launch: bool = False
    reads_raw: bool = False
    frame_for: tuple[str, ...] = ()
    optional_products: tuple[str, ...] = ()


@dataclass(frozen=True)
class Stage:
    """One pipeline stage, declared once in its module (``STAGE``); everything else about the graph derives from it.

    * ``name``, ``products`` (what it publishes), ``inputs`` (what it needs and reads: :class:`StageInputs`);
    * ``options``: its options model (:mod:`hadal.settings`), read from the configuration ``section`` (default: the
      stage's name); ``param_fields``: the fields of a shared section it uses (its cache fingerprint and manifests
      record only those, so a laser setting does not re-run the DTM); ``None``: all;
    * ``run(ctx) -> {product: ProductVersion}``: do the work and publish;
    * ``skip_reason(ctx) -> str | None``: a check of the upstream *content* made just before it would run (e.g.
      ``match`` needs an altimeter and dead reckoning in ``ctd``);
    * ``planned_products(dive, made) -> made``: products that depend on dive.yaml hints (derive's ``trajectory``);
    * ``raw_files(ctx) -> [Path]``: files its settings point at, part of its cache fingerprint;
    * ``warm_imports``: modules its run imports, imported ahead (``"pkg.mod"`` or ``"pkg.mod:function"``,
      :func:`hadal.childproc.warm`);
    * ``process``: a flow runs it in its own process when another stage can run beside it (CPU-bound gridding).
    """

    name: str
    products: tuple[str, ...]
    inputs: StageInputs
    options: type[BaseModel]
    run: Callable[[StageContext], dict[str, ProductVersion]]
    section: str = ""
    param_fields: tuple[str, ...] | None = None
    skip_reason: Callable[[StageContext], str | None] | None = None
    planned_products: Callable[[Any, tuple[str, ...]], tuple[str, ...]] | None = None
    raw_files: Callable[[StageContext], list[Path]] | None = None
    warm_imports: tuple[str, ...] = ()
    process: bool = False

    @property
    def config_section(self) -> str:
        """The configuration section it reads (``grid`` for ``dtm`` and ``laser``)."""
        return self.section or self.name

    @property
    def reads(self) -> tuple[str, ...]:
        """Every product it reads (required, then optional): its graph edges and its cache fingerprint's upstream."""
        return tuple(dict.fromkeys((*self.inputs.upstream, *self.inputs.optional_upstream)))


@dataclass
class StageContext:
    """Everything a stage needs: the dive, its raw directory, the store, the configuration."""

    dive: Dive
    raw_dir: Path
    store: ProductStore
    config: PipelineConfig
    progress: Progress = field(default_factory=NullProgress)
    log: logging.Logger = field(default_factory=lambda: logging.getLogger("hadal"))
    #: product -> the version this run reads (found at the run's start or published by it); see upstream()
    pins: dict[str, ProductVersion] = field(default_factory=dict)
    #: stages that failed earlier in this run (``{stage: one-line error}``) and the stages skipped because of
    #: them (``{stage: reason}``); the report lists both
    failed: dict[str, str] = field(default_factory=dict)
    failed_skips: dict[str, str] = field(default_factory=dict)

    @property
    def dive_id(self) -> str:
        return self.dive.dive_id

    def upstream(self, product: str) -> ProductVersion:
        """The upstream version this run uses, verified against its manifest, or a clear :class:`StageError`.

        A run pins the versions it found at its start and those it published (:attr:`pins`), so two concurrent
        runs of one dive never mix each other's inputs; without a pin it is the latest published version.
        Files changed since they were published are a :class:`StoreError` (:meth:`ProductStore.check_intact`).
        """
        pv = self.pins.get(product)
        if pv is None:
            if not self.store.has(self.dive_id, product):
                raise StageError(
                    f"dive {self.dive_id!r} has no {product!r} product yet; run the stage that makes it first "
                    f"(hadal stage {producer_of(product)} {self.raw_dir})"
                )
            pv = self.store.latest(self.dive_id, product)
        self.store.check_intact(pv)
        return pv

    def optional_upstream(self, product: str) -> ProductVersion | None:
        """:meth:`upstream` when the product exists (pinned or published), else ``None``."""
        if product in self.pins or self.store.has(self.dive_id, product):
            return self.upstream(product)
        return None

    def pin_existing(self, products: Iterable[str]) -> None:
        """Pin the latest published version of each of ``products`` that exists (a run's start)."""
        for product in products:
            if product not in self.pins and self.store.has(self.dive_id, product):
                self.pins[product] = self.store.latest(self.dive_id, product)

    def params(self, stage: str) -> dict[str, Any]:
        """Stage ``stage``'s parameters: its configuration section (:attr:`Stage.config_section`), only the fields it
        uses (:attr:`Stage.param_fields`) when the section is shared; canonical for fingerprints/manifests."""
        from hadal.stages.graph import stage as stage_record

        rec = stage_record(stage) if stage in STAGE_ORDER else None
        section = self.config.section(rec.config_section if rec is not None else stage)
        if section is None:
            return {}
        fields = rec.param_fields if rec is not None else None
        return section.model_dump(mode="json", include=set(fields) if fields is not None else None)


def available_stages() -> list[str]:
    """The stages, in execution order (:data:`hadal.stages.graph.STAGES`)."""
    return list(STAGE_ORDER)


def producer_of(product: str) -> str:
    """The stage that publishes ``product`` (``?`` for none)."""
    from hadal.stages.graph import producer_of as _producer_of

    return _producer_of(product)
