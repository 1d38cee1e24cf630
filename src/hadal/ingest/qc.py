"""QARTOD quality-control flags for the sensor table, computed with ``ioos_qc.qartod``.

Flags (IOOS QARTOD manual, 2020): 1 good, 2 not evaluated, 3 suspect, 4 bad, 9 missing. Per variable the
gross-range, spike and flat-line tests of ``ioos_qc`` are run and aggregated with
``ioos_qc.qartod.qartod_compare`` (worst flag wins); a NaN value is flag 9 whatever the tests say
(no data after alignment: gap, dropout, outside the sensor's time span).

The SBE49's pressure sensor saturates at 10 500 dbar: pressure_ctd_dbar at or above the saturation value
is flagged 4 by running the gross-range test with a fail span whose upper end is the largest double below
the saturation value (``ioos_qc`` flags values strictly outside the span).

The spike test is ``ioos_qc.qartod.spike_test`` (method "average") re-expressed without its per-sample Python
loop over the masks (:func:`spike_test_flags`: 0.21 s -> 0.012 s a variable on 567 k samples, 17x);
``tests/unit/ingest/test_qc_spike.py`` checks it flag for flag against the library on series with NaN/inf runs, huge values
and every threshold form.

Deviation from ``ioos_qc.qartod.flat_line_test`` (flat line only; gross range is the library's):
the library (a) converts its time thresholds to a sample count with the median sampling interval rounded
to whole seconds, which is 0 s for a 16 Hz CTD, and (b) materialises an ``n x window`` strided masked array
(a 16 Hz dive of 10 h with a 300 s window would need ~22 GB). :func:`flat_line_flags` implements the same
definition - point ``j`` is flagged when the range of the ``count + 1`` samples ending at ``j`` (NaN ignored)
is below ``tolerance``, ``count = threshold_s / median_dt``, no flag before the first full window - with
O(n) rolling max/min. ``tests/unit/ingest/test_ingest_units_align_qc.py`` checks it against ``ioos_qc`` flag for flag.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from hadal.settings.qc import DEFAULT_QC, VariableQC

if TYPE_CHECKING:
    import numpy as np

__all__ = ["VariableQC", "DEFAULT_QC", "merge_qc", "qc_flags", "qc_table", "flat_line_flags", "combine_flags",
           "spike_test_flags", "FILL_VALUES_ANY", "FILL_ALWAYS", "fill_mask", "fail_fraction"]

GOOD, NOT_EVALUATED, SUSPECT, BAD, MISSING = 1, 2, 3, 4, 9


def merge_qc(overrides: Any = None) -> dict[str, VariableQC]:
    """:data:`DEFAULT_QC` with ``overrides`` (variable -> :class:`VariableQC` or mapping) merged **test by test**:
    only the fields an override sets (``model_fields_set``; ``null`` switches a test off) replace the default's,
    so ``pressure_ctd_dbar: {fail_span: [-10, 11000]}`` keeps the saturation, spike and flat-line tests. A
    variable that is not a sensor-table variable is a :class:`~hadal.errors.ConfigError` (a misspelt name)."""
    from pydantic import ValidationError

    from hadal.errors import ConfigError, first_validation_error

    out = dict(DEFAULT_QC)
    for var, ov in dict(overrides or {}).items():
        if var not in DEFAULT_QC:
            raise ConfigError(f"ingest.qc: unknown variable {var!r} (known: {', '.join(DEFAULT_QC)})")
        try:
            if not isinstance(ov, VariableQC):
                ov = VariableQC.model_validate(ov)
            if ov is DEFAULT_QC[var]:
                continue
            out[var] = VariableQC.model_validate({**DEFAULT_QC[var].model_dump(), **ov.model_dump(
                include=set(ov.model_fields_set))})
        except ValidationError as exc:
            loc, msg, _ = first_validation_error(exc)
            raise ConfigError(f"ingest.qc.{var}{'.' + loc if loc else ''}: {msg}") from None
    return out


def qc_flags(values: np.ndarray, time_ns: np.ndarray, cfg: VariableQC) -> np.ndarray:
    """QARTOD flags (uint8) of one variable; see the module docstring."""
    import numpy as np
    from ioos_qc import qartod

    x = np.asarray(values, dtype=np.float64)
    results = []
    if cfg.fail_span is not None or cfg.saturation is not None:
        lo, hi = sorted(cfg.fail_span) if cfg.fail_span else (-np.inf, np.inf)
        if cfg.saturation is not None:
            hi = min(hi, float(np.nextafter(cfg.saturation, -np.inf)))
        sus = None
        if cfg.suspect_span is not None:
            slo, shi = sorted(cfg.suspect_span)
            sus = (max(slo, lo), min(shi, hi))
        results.append(np.ma.filled(qartod.gross_range_test(inp=x, fail_span=(lo, hi), suspect_span=sus), MISSING))
    if cfg.spike_suspect is not None and x.size >= 3:
        results.append(spike_test_flags(x, cfg.spike_suspect, cfg.spike_fail))
    if cfg.flat_line_suspect_s is not None and x.size >= 3:
        t = np.asarray(time_ns, dtype=np.int64)
        dt = float(np.median(np.diff(t))) / 1e9 if t.size > 1 else 0.0
        if dt > 0:
            n_sus = max(int(cfg.flat_line_suspect_s / dt), 1)
            n_fail = max(int((cfg.flat_line_fail_s or cfg.flat_line_suspect_s) / dt), n_sus)
            results.append(flat_line_flags(x, n_sus, n_fail, cfg.flat_line_tolerance))
    return combine_flags(results, x)


def spike_test_flags(values: np.ndarray, suspect_threshold: float | None,
                     fail_threshold: float | None) -> np.ndarray:
    """QARTOD spike test flags (uint8), exactly ``numpy.ma.filled(ioos_qc.qartod.spike_test(values,
    suspect_threshold, fail_threshold, method="average"), 2)`` without the library's per-sample loop.

    ``diff[n] = |x[n] - (x[n-1] + x[n+1]) / 2|`` (values' units); 3 where ``diff`` exceeds a truthy
    ``suspect_threshold``, 4 where it exceeds a truthy ``fail_threshold``, 1 elsewhere; 2 at both ends and where
    a neighbour is missing (or their sum is within a factor 2 of overflow, as ``numpy.ma`` divides); 9 where the
    value itself is not finite.
    """
    import numpy as np

    x = np.asarray(values, dtype=np.float64).reshape(-1)
    missing = ~np.isfinite(x)
    n = x.size
    ref = np.zeros(n)
    unknown = missing.copy()
    with np.errstate(over="ignore", invalid="ignore"):
        pair = x[:-2] + x[2:]
        ref[1:-1] = pair / 2
        # numpy.ma's safe division (the library's ``/ 2``) masks |a| * tiny >= |b|, i.e. |pair| >= 2 / tiny
        unknown[1:-1] |= missing[:-2] | missing[2:] | (np.abs(pair) * np.finfo(np.float64).tiny >= 2)
        diff = np.abs(x - ref)
        flags = np.ones(n, np.uint8)
        if suspect_threshold:
            flags[(diff > suspect_threshold) & ~unknown] = SUSPECT
        if fail_threshold:
            flags[(diff > fail_threshold) & ~unknown] = BAD
    if n:
        flags[0] = flags[-1] = NOT_EVALUATED
    flags[unknown] = NOT_EVALUATED
    flags[missing] = MISSING
    return flags


def combine_flags(results: list[np.ndarray], x: np.ndarray) -> np.ndarray:
    """The QARTOD aggregate (``qartod_compare``, uint8) of the tests' ``results`` on the series ``x``: 2 (not
    evaluated) everywhere when no test ran, 9 (missing) where ``x`` is not finite."""
    import numpy as np
    from ioos_qc import qartod

    if results:
        flags = np.asarray(qartod.qartod_compare(results), dtype=np.uint8)
    else:
        flags = np.full(x.size, NOT_EVALUATED, dtype=np.uint8)
    flags[~np.isfinite(x)] = MISSING
    return flags


def flat_line_flags(x: np.ndarray, suspect_count: int, fail_count: int, tolerance: float) -> np.ndarray:
    """ioos_qc's flat-line test in samples, O(n): see the module docstring (flags 1, 3, 4, 9)."""
    import numpy as np
    import pandas as pd

    x = np.asarray(x, dtype=np.float64)
    flags = np.full(x.size, GOOD, dtype=np.uint8)
    s = pd.Series(np.where(np.isfinite(x), x, np.nan))
    for count, flag in ((suspect_count, SUSPECT), (fail_count, BAD)):
        if count >= x.size:
            continue
        r = s.rolling(count + 1, min_periods=1)
        rng = (r.max() - r.min()).to_numpy()
        hit = np.zeros(x.size, dtype=bool)
        with np.errstate(invalid="ignore"):
            hit[count:] = rng[count:] < tolerance
        flags[hit] = flag
    flags[~np.isfinite(x)] = MISSING
    return flags


#: Sea-Bird's ``bad_flag`` (SeaSoft, "Seasave V7 manual", .cnv format): a fill value for every variable, whatever
#: its range (it is ~0, inside most ranges: no real sensor reports it)
FILL_ALWAYS: tuple[float, ...] = (-9.99e-29,)
#: saturation/"nines" sentinels loggers write for a dead or absent sensor (9.9e5 uS/cm of a failed conductivity
#: cell, 9.99e5, 9.999e5, 9.9999e5, the netCDF default fill 9.96921e36 and 9.9e37): fill values for every variable
#: as logged, but only where they also lie outside the variable's fail span once converted (990000 Pa is a real
#: 99 dbar). A lone 99 999 is not among them: it stays a value, flagged 4 by the gross-range test.
FILL_VALUES_ANY: tuple[float, ...] = (9.9e5, 9.99e5, 9.999e5, 9.9999e5, 9.96921e36, 9.9e37, -9.9e37)


def fill_mask(raw: np.ndarray, canonical: np.ndarray, cfg: VariableQC | None) -> np.ndarray:
    """True where a value is a fill value (missing data, flag 9), by the explicit rule: ``raw`` (the values as
    logged) equals (relative tolerance 1e-6) one of :data:`FILL_ALWAYS`, or one of :data:`FILL_VALUES_ANY` or the
    variable's own ``cfg.fill_values`` while ``canonical`` (the same values in the variable's unit) lies outside
    ``cfg.fail_span`` (without a fail span: always). NaN is missing already and not counted here."""
    import numpy as np

    raw = np.asarray(raw, dtype=np.float64)
    can = np.asarray(canonical, dtype=np.float64)

    def _hits(values: tuple[float, ...]) -> np.ndarray:
        m = np.zeros(raw.shape, dtype=bool)
        for f in values:
            m |= np.isclose(raw, f, rtol=1e-6, atol=0.0)
        return m

    out = _hits(FILL_ALWAYS)
    cand = _hits(FILL_VALUES_ANY + tuple(cfg.fill_values if cfg is not None else ()))
    if cand.any():
        if cfg is not None and cfg.fail_span is not None:
            lo, hi = sorted(cfg.fail_span)
            with np.errstate(invalid="ignore"):
                cand &= (can < lo) | (can > hi)
        out |= cand
    return out


def fail_fraction(values: np.ndarray, cfg: VariableQC) -> float:
    """Fraction of the finite values outside the fail span (0 when there are none)."""
    import numpy as np

    x = np.asarray(values, dtype=np.float64)
    x = x[np.isfinite(x)]
    if x.size == 0 or cfg.fail_span is None:
        return 0.0
    lo, hi = sorted(cfg.fail_span)
    return float(np.count_nonzero((x < lo) | (x > hi)) / x.size)


def qc_table(columns: dict[str, np.ndarray], time_ns: np.ndarray, config: dict[str, VariableQC]
             ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, int]]]:
    """Flags for every variable in ``columns`` (``<var>_qc``) and per-variable flag counts."""
    import numpy as np

    flags, counts = {}, {}
    for var, x in columns.items():
        cfg = config.get(var, VariableQC())
        f = qc_flags(x, time_ns, cfg)
        flags[f"{var}_qc"] = f
        vals, n = np.unique(f, return_counts=True)
        counts[var] = {str(int(k)): int(c) for k, c in zip(vals, n, strict=True)}
    return flags, counts
