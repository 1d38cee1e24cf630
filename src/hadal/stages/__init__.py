"""Pipeline stages: Prefect-free functions that read inputs from the store and publish new versions.

Each stage module ``hadal.stages.<name>`` defines

* ``Params`` — its options, a pydantic model declared in :mod:`hadal.settings` (its section of
  :class:`hadal.settings.PipelineConfig`);
* ``PRODUCTS`` — the product names it publishes; ``UPSTREAM`` — the products it reads;
* ``INPUTS`` — a :class:`StageInputs`: the raw source kinds and upstream products it needs, from which
  :mod:`hadal.plan` decides whether it runs on a dive (stages without their inputs are skipped with a reason);
* optionally ``skip_reason(ctx) -> str | None`` — a check of the upstream *content* made just before the
  stage would run (e.g. ``match`` needs an altimeter and dead reckoning in ``ctd``);
* ``run(ctx: StageContext) -> dict[str, ProductVersion]`` — do the work and publish.

* optionally ``SECTION`` — the configuration section it reads when that is not named after it (``dtm`` and
  ``laser`` share ``grid``) and ``PARAM_FIELDS`` — the fields of that section it uses (its cache fingerprint and
  manifests record only those, so a laser setting does not re-run the DTM).

The Prefect tasks in ``tasks/`` are thin wrappers around ``run``; the flow in ``flows/`` runs each as soon as the
stages it reads from are done. Data flows one way: raw → ingest → derive; raw → dtm → suitability → match;
raw → laser → landing; all → report. ``grid`` names the two gridding stages together (:data:`STAGE_GROUPS`).
"""

from __future__ import annotations

import importlib
import logging
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

from hadal.errors import StageError

if TYPE_CHECKING:
    from hadal.dive import Dive
    from hadal.settings import PipelineConfig
    from hadal.store import ProductStore, ProductVersion

T = TypeVar("T")

#: Stages in execution order (also the flow's priority among ready stages). Only stages whose module defines
#: ``run`` are part of the pipeline.
STAGE_ORDER: tuple[str, ...] = ("ingest", "derive", "dtm", "laser", "suitability", "match", "landing", "report")

#: Names that stand for several stages wherever a stage is named (``hadal stage grid``, ``run_stage("grid")``):
#: ``grid`` is the DTM and the laser grids, one stage before they were split so that each runs (and re-runs)
#: on its own inputs and parameters.
STAGE_GROUPS: dict[str, tuple[str, ...]] = {"grid": ("dtm", "laser")}


@dataclass(frozen=True)
class StageInputs:
    """What a stage needs to run on a dive (declared next to its ``Params``; used by :mod:`hadal.plan`).

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


class Progress(Protocol):
    def track(self, it: Iterable[T], description: str, total: int | None = None) -> Iterator[T]: ...


class NullProgress:
    """Progress reporter that reports nothing (library default)."""

    def track(self, it: Iterable[T], description: str, total: int | None = None) -> Iterator[T]:
        yield from it


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
        """Stage ``stage``'s parameters: its configuration section (``SECTION``, default the stage's name), only
        the fields it uses (``PARAM_FIELDS``) when the section is shared; canonical for fingerprints/manifests."""
        mod = stage_module(stage) if stage in STAGE_ORDER else None
        section = self.config.section(getattr(mod, "SECTION", stage))
        if section is None:
            return {}
        fields = getattr(mod, "PARAM_FIELDS", None)
        return section.model_dump(mode="json", include=set(fields) if fields is not None else None)


def stage_module(name: str) -> ModuleType:
    if name not in STAGE_ORDER:
        group = f" ({name} stands for {', '.join(STAGE_GROUPS[name])})" if name in STAGE_GROUPS else ""
        raise StageError(f"unknown stage {name!r}{group}; stages are: {', '.join(available_stages())}")
    return importlib.import_module(f"hadal.stages.{name}")


def warm(entry: str) -> bool:
    """One entry of a stage's ``WARM_IMPORTS``, done ahead of the stage (while Prefect's server boots, or in a stage
    process started ahead): ``"pkg.module"`` is imported; ``"pkg.module:function"`` is imported and the function
    called (a first-use cost that is not an import, e.g. matplotlib's first figure: :func:`hadal.mplwarm.first_draw`).
    False when it fails: the stage itself then reports the problem in its own words."""
    mod, _, func = entry.partition(":")
    try:
        m = importlib.import_module(mod)
        if func:
            getattr(m, func)()
    except Exception:  # noqa: BLE001 - the stage itself reports a broken import
        return False
    return True


def available_stages() -> list[str]:
    """Stages that are implemented (define ``run``), in execution order."""
    out = []
    for n in STAGE_ORDER:
        try:
            mod = importlib.import_module(f"hadal.stages.{n}")
        except ModuleNotFoundError:
            continue
        if callable(getattr(mod, "run", None)):
            out.append(n)
    return out


def producer_of(product: str) -> str:
    for n in available_stages():
        if product in getattr(stage_module(n), "PRODUCTS", ()):
            return n
    return "?"
