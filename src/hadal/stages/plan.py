"""Which stages a dive's data supports: the run plan.

Every stage declares its inputs (:class:`hadal.stages.StageInputs`, in its record
:class:`hadal.stages.Stage`). :func:`plan_stages` walks the stages in order and, from the raw source kinds the dive lists
and the products earlier stages will publish (or that are already in the store), decides for each one
whether it runs or is skipped, and why. ``report`` always runs and lists the skipped stages.

A stage's record may also give ``skip_reason(ctx) -> str | None``, a check of its upstream products' *content*
made just before it would run (:func:`runtime_skip_reason`), e.g. ``match`` needs an altimeter and a
dead-reckoned track in ``ctd``, which a CTD-only dive does not have.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

from hadal.errors import StageError
from hadal.stages import STAGE_GROUPS, STAGE_ORDER, StageInputs, available_stages
from hadal.stages.graph import all_products, dependencies, producer_of, stage

if TYPE_CHECKING:
    from hadal.dive import Dive
    from hadal.stages import StageContext
    from hadal.store import ProductStore

_KIND_NAMES = {
    "mcap": "MCAP vehicle log", "csv": "CSV vehicle log", "cnv": "Sea-Bird cast (.cnv/.hex)",
    "multibeam": "multibeam soundings", "prior_grid": "prior bathymetry grid", "laser": "laser bathymetry",
    "vehicle_swath": "vehicle swath soundings",
}


@dataclass(frozen=True)
class PlannedStage:
    """One stage of the plan: ``run`` or not, the ``reason`` when skipped, the products it will make."""

    name: str
    run: bool
    reason: str = ""
    products: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def stage_inputs(name: str) -> StageInputs:
    """The declared inputs of stage ``name``."""
    return stage(name).inputs


def _kinds_text(kinds: Sequence[str]) -> str:
    return " or ".join(_KIND_NAMES.get(k, k) for k in kinds)


def plan_stages(dive: Dive, stages: Sequence[str] | None = None, store: ProductStore | None = None
                ) -> list[PlannedStage]:
    """The plan for ``dive``: every stage of ``stages`` (default all, in :data:`STAGE_ORDER`) with run/skip.

    Products count as available when an earlier planned stage makes them or, with ``store``, when the
    dive already has a published version (so ``hadal stage derive DIR`` runs on an earlier ingest).
    """
    names = resolve_stages(stages)
    present = set(dive.sources.kinds())
    available: set[str] = set()
    if store is not None:
        available |= {p for p in all_products() if store.has(dive.dive_id, p)}
    out: list[PlannedStage] = []
    for name in names:
        rec = stage(name)
        inp = rec.inputs
        produces = rec.products
        reason = ""
        if inp.raw_any and not present.intersection(inp.raw_any):
            reason = f"the dive lists no {_kinds_text(inp.raw_any)} in dive.yaml sources"
        else:
            missing = [u for u in inp.upstream if u not in available]
            if missing:
                reason = "needs " + "; ".join(_why_missing(u, out) for u in missing)
        if reason and not inp.always:
            out.append(PlannedStage(name, False, reason))
            continue
        made = tuple(p for p in produces if p not in inp.optional_products
                     and (p not in inp.product_sources or present.intersection(inp.product_sources[p])))
        if rec.planned_products is not None:  # a stage whose products depend on dive.yaml hints (derive)
            made = tuple(rec.planned_products(dive, made))
        available.update(made)
        out.append(PlannedStage(name, True, "", made))
    return out


def _why_missing(product: str, plan: list[PlannedStage]) -> str:
    maker = producer_of(product)
    sources = stage_inputs(maker).product_sources.get(product) if maker != "?" else None
    if sources:
        return f"{product} (made by {maker} from {_kinds_text(sources)}, which the dive does not list)"
    if any(p.name == maker and not p.run for p in plan):
        return f"{product} (stage {maker} is skipped)"
    ran = next((p for p in plan if p.name == maker and p.run), None)
    if ran is not None:  # the maker runs but does not make it for this dive (derive of an underway-only record)
        made = ", ".join(ran.products) or "nothing"
        return f"{product} (stage {maker} makes {made} for this dive, not {product})"
    return f"{product} (run stage {maker} first)"


def check_plan(dive: Dive, plan: list[PlannedStage]) -> None:
    """Refuse, in one line naming them, a plan whose running stages need a map frame or a launch position the
    dive lacks."""
    from hadal.errors import ConfigError

    if dive.map_frame is None and dive.launch is None:
        need = [ps.name for ps in plan if ps.run and set(ps.products) & set(stage_inputs(ps.name).frame_for)]
        if need:
            raise ConfigError(
                f"dive {dive.dive_id!r}: stage(s) {', '.join(need)} need a map frame, but dive.yaml has neither "
                "'map_frame' nor 'launch' (hadal init takes it from lon/lat data; for projected x/y data add their "
                "crs to the source entry, or give --launch LAT,LON)")
    if dive.launch is not None:
        return
    need = [ps.name for ps in plan if ps.run and stage_inputs(ps.name).needs_launch]
    if need:
        raise ConfigError(
            f"dive {dive.dive_id!r}: dive.yaml has no 'launch', which stage(s) {', '.join(need)} need (the origin "
            "of the dead-reckoned track); add launch: {latitude_deg: .., longitude_deg: ..} or run "
            "'hadal init DIR --launch LAT,LON --force'")


def runtime_skip_reason(name: str, ctx: StageContext) -> str | None:
    """The stage's own content check (:attr:`Stage.skip_reason`) just before it runs; ``None`` = run it."""
    check = stage(name).skip_reason
    return check(ctx) if check is not None else None


def skipped_stages(ctx: StageContext) -> list[dict[str, str]]:
    """Stages that did not run on this dive, with the reason: failed in this run (``ctx.failed``), skipped because
    of a failure, or not supported by the data (static plan and content checks); for the report."""
    out = [{"stage": name, "reason": f"failed: {err}"} for name, err in ctx.failed.items()]
    out += [{"stage": name, "reason": why} for name, why in ctx.failed_skips.items()]
    done = set(ctx.failed) | set(ctx.failed_skips)
    for ps in plan_stages(ctx.dive, store=None):
        if ps.name in done:
            continue
        if not ps.run:
            out.append({"stage": ps.name, "reason": ps.reason})
            continue
        if ps.name == "report":
            continue
        try:
            why = runtime_skip_reason(ps.name, ctx)
        except Exception as exc:  # noqa: BLE001 - a report must not fail on a check; say what happened
            why = f"could not be checked ({type(exc).__name__})"
        if why:
            out.append({"stage": ps.name, "reason": why})
    return out


def format_plan(plan: list[PlannedStage]) -> str:
    """One line per stage: ``run`` with its products, or ``skip`` with the reason."""
    lines = []
    for ps in plan:
        if ps.run:
            lines.append(f"  run   {ps.name:<12s} -> {', '.join(ps.products) or '-'}")
        else:
            lines.append(f"  skip  {ps.name:<12s} ({ps.reason})")
    return "\n".join(lines)


def stage_dependencies(names: Sequence[str]) -> dict[str, set[str]]:
    """For each stage of a run (``names``), the stages *of that run* it must wait for: those that make a product
    it reads. Stages with no path between them (``grid`` and ``ingest``/``derive``; ``landing`` and ``match``) run
    concurrently in the flow."""
    return dependencies(names)


def downstream_stages(name: str, stages: Sequence[str] | None = None) -> list[str]:
    """The stages (of ``stages``, default all, in :data:`STAGE_ORDER`) that depend on ``name`` (a stage or a group
    such as ``grid``) directly or through other stages (``hadal stage NAME --downstream``); ``name`` itself (the
    group's stages) not included."""
    names = resolve_stages(stages)
    deps = stage_dependencies(names)
    start = set(STAGE_GROUPS.get(name, (name,)))
    out: set[str] = set()
    frontier = set(start)
    while frontier:
        frontier = {n for n in names if n not in out and n not in start and deps[n] & frontier}
        out |= frontier
    return [n for n in names if n in out]


def resolve_stages(stages: Sequence[str] | None = None) -> list[str]:
    """Validate a stage selection (group names such as ``grid`` expanded: :data:`hadal.stages.STAGE_GROUPS`) and
    return it in execution order (all implemented stages by default)."""
    avail = available_stages()
    if not stages:
        return avail
    named = {m for s in stages for m in STAGE_GROUPS.get(s, (s,))}
    unknown = [s for s in named if s not in STAGE_ORDER]
    if unknown:
        groups = "; ".join(f"{g} = {' + '.join(m)}" for g, m in STAGE_GROUPS.items())
        raise StageError(f"unknown stage(s) {', '.join(sorted(unknown))}; stages are: {', '.join(avail)} "
                         f"({groups})")
    missing = [s for s in named if s not in avail]
    if missing:
        raise StageError(f"stage(s) {', '.join(sorted(missing))} not implemented; available: {', '.join(avail)}")
    return [s for s in STAGE_ORDER if s in named]
