"""QARTOD flags on what ``derive`` computes: salinity, density, sound speed, depth and seafloor depth.

Issue 17 §3. Flags (IOOS QARTOD manual, 2020; ``ioos_qc.qartod``): 1 pass, 2 not evaluated, 3 suspect, 4 fail,
9 missing. For each derived variable (:data:`DERIVED`):

* ``ioos_qc.qartod.gross_range_test`` with a *fail span* (outside: physically impossible for a full-ocean
  dive, flag 4) and a *suspect span* (outside: possible but unusual, or outside the formula's validity such as
  PSS-78's 2-42, flag 3);
* the QARTOD spike test where thresholds are given (salinity, seafloor depth): ``ioos_qc.qartod.spike_test``
  as :func:`hadal.ingest.qc.spike_test_flags` computes it without its per-sample loop;
* the inputs it is computed from are range-checked the same way (temperature, conductivity, fused pressure,
  latitude, longitude, altitude) and the derived value inherits the worst input flag (``depends_on``): a
  salinity computed from T = 99 °C is flag 4 even when its value looks plausible, a depth from latitude 91°
  is flag 4;
* the results are combined with ``ioos_qc.qartod.qartod_compare`` (worst wins); a NaN value is flag 9.

The default thresholds are shipped in ``hadal/data/qc_derived.yaml`` (documented there) and loaded into the
typed :class:`DerivedQCConfig`; ``derive.qc_thresholds`` in ``config/pipeline.yaml`` overrides entries.
Functions here are pure (arrays and tables in, flags and counts out); the stage calls :func:`qc_derived_table`
and :func:`qc_profile`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from hadal.settings.qc import DerivedQCConfig, DerivedVariableQC, load_qc_config

if TYPE_CHECKING:
    import numpy as np
    import pandas as pd

__all__ = ["DerivedVariableQC", "DerivedQCConfig", "DERIVED", "FLAG_MEANINGS", "load_qc_config", "flags_for", "apply_to_table",
           "qc_derived_table", "qc_profile", "flag_summary", "qc_field_attrs"]

GOOD, NOT_EVALUATED, SUSPECT, BAD, MISSING = 1, 2, 3, 4, 9
FLAG_MEANINGS = {1: "pass", 2: "not_evaluated", 3: "suspect", 4: "fail", 9: "missing"}
#: derived variables flagged (the ``<name>_qc`` columns derive adds)
DERIVED = ("practical_salinity", "density_kg_m3", "sound_speed_m_s", "depth_m", "seafloor_depth_m")


def flags_for(values: Any, cfg: DerivedVariableQC) -> np.ndarray:
    """QARTOD flags (uint8) of one series: gross range (fail/suspect spans) and spike tests of ``ioos_qc``,
    combined with ``qartod_compare``; NaN is 9; 2 where no test is configured."""
    import numpy as np
    from ioos_qc import qartod

    from hadal.ingest.qc import combine_flags, spike_test_flags

    x = np.asarray(values, dtype=np.float64).reshape(-1)
    results = []
    if cfg.fail_span is not None or cfg.suspect_span is not None:
        fail = cfg.fail_span or (-np.inf, np.inf)
        results.append(np.ma.filled(qartod.gross_range_test(inp=x, fail_span=fail, suspect_span=cfg.suspect_span),
                                    MISSING))
    if cfg.spike_suspect is not None and x.size >= 3:
        results.append(spike_test_flags(x, cfg.spike_suspect, cfg.spike_fail or np.inf))
    return combine_flags(results, x)


def _worst(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """QARTOD precedence (4 > 3 > 1 > 2, 9 only where both are 9) via ``qartod_compare``."""
    import numpy as np
    from ioos_qc import qartod

    return np.asarray(qartod.qartod_compare([a, b]), dtype=np.uint8)


def _input_flags(name: str, values: Any, n: int, cfg: DerivedQCConfig) -> np.ndarray | None:
    import numpy as np

    c = cfg.inputs.get(name)
    if c is None or values is None:
        return None
    v = np.broadcast_to(np.asarray(values, dtype=np.float64), (n,))
    f = flags_for(v, c)
    # a missing input is not a reason to flag what it did not produce: it stays 'not evaluated' for the inheritance
    f[f == MISSING] = NOT_EVALUATED
    return f


def qc_derived_table(df: pd.DataFrame, cfg: DerivedQCConfig, *, latitude_deg: float,
                     longitude_deg: float | None = None, input_columns: Mapping[str, str] | None = None
                     ) -> dict[str, np.ndarray]:
    """``{<var>_qc: flags}`` for the derived variables of :data:`DERIVED` present in ``df`` (and for the range-
    checked inputs, ``<input>_range_qc``), see the module docstring. ``latitude_deg``/``longitude_deg``: the
    position used for gravity/depth. ``input_columns`` maps an input name to the column holding it (default:
    the same name)."""
    import numpy as np

    n = len(df)
    cols = dict(input_columns or {})
    scalars = {"latitude_deg": latitude_deg, "longitude_deg": longitude_deg}
    inputs: dict[str, np.ndarray] = {}
    for name in cfg.inputs:
        if name in scalars:
            vals = None if scalars[name] is None else float(scalars[name])
        else:
            col = cols.get(name, name)
            vals = df[col].to_numpy(np.float64) if col in df.columns else None
        f = _input_flags(name, vals, n, cfg)
        if f is not None:
            inputs[name] = f
    out: dict[str, np.ndarray] = {f"{k}_range_qc": v for k, v in inputs.items()
                                  if k not in scalars}
    for var in DERIVED:
        c = cfg.derived.get(var)
        if c is None or var not in df.columns:
            continue
        f = flags_for(df[var].to_numpy(np.float64), c)
        finite = f != MISSING
        for dep in c.depends_on:
            if dep in inputs:
                inherited = np.where(inputs[dep] >= SUSPECT, inputs[dep], GOOD).astype(np.uint8)
                f[finite] = _worst(f[finite], inherited[finite])
        out[f"{var}_qc"] = f
    return out


def flag_summary(flags: Mapping[str, np.ndarray]) -> dict[str, dict[str, Any]]:
    """Per variable: count of each flag (by meaning) and the fraction flagged 3 or 4 — for the report."""
    import numpy as np

    out: dict[str, dict[str, Any]] = {}
    for name, f in flags.items():
        var = name[:-3] if name.endswith("_qc") else name
        a = np.asarray(f).reshape(-1)
        counts = {FLAG_MEANINGS[k]: int(np.count_nonzero(a == k)) for k in FLAG_MEANINGS}
        valid = a.size - counts["missing"]
        out[var] = {"counts": counts, "samples": int(a.size),
                    "flagged_fraction": round((counts["suspect"] + counts["fail"]) / valid, 6) if valid else 0.0}
    return out


def _tests_comment(cfg: DerivedVariableQC) -> str:
    parts = []
    if cfg.fail_span:
        parts.append(f"fail outside [{cfg.fail_span[0]:g}, {cfg.fail_span[1]:g}]")
    if cfg.suspect_span:
        parts.append(f"suspect outside [{cfg.suspect_span[0]:g}, {cfg.suspect_span[1]:g}]")
    if cfg.spike_suspect:
        parts.append(f"spike suspect > {cfg.spike_suspect:g}" + (f", fail > {cfg.spike_fail:g}" if cfg.spike_fail else ""))
    if cfg.depends_on:
        parts.append("inherits the worst range flag of " + ", ".join(cfg.depends_on))
    return "QARTOD (ioos_qc): " + "; ".join(parts)


def qc_field_attrs(columns: Any, cfg: DerivedQCConfig) -> dict[str, dict[str, str]]:
    """Field metadata for the Parquet writer: ``ancillary_variables`` on each flagged variable and, on each
    ``<var>_qc``, the CF flag attributes with a comment naming the tests and thresholds."""
    cols = set(map(str, columns))
    out: dict[str, dict[str, str]] = {}
    meanings = " ".join(FLAG_MEANINGS.values())
    values = " ".join(map(str, FLAG_MEANINGS))
    for var in DERIVED:
        if f"{var}_qc" in cols and var in cols:
            out[var] = {"ancillary_variables": f"{var}_qc"}
            out[f"{var}_qc"] = {"long_name": f"QARTOD flag of {var}", "standard_name": "aggregate_quality_flag",
                                "flag_values": values, "flag_meanings": meanings,
                                "comment": _tests_comment(cfg.derived[var])}
    for name, c in cfg.inputs.items():
        if f"{name}_range_qc" in cols:
            out[f"{name}_range_qc"] = {"long_name": f"QARTOD range flag of the derive input {name}",
                                       "standard_name": "aggregate_quality_flag", "flag_values": values,
                                       "flag_meanings": meanings, "comment": _tests_comment(c)}
    return out


def qc_profile(ds: Any, cfg: DerivedQCConfig) -> dict[str, dict[str, Any]]:
    """Add ``<var>_qc`` (gross range on the binned means; 9 for an empty bin) to a profile dataset for each
    variable of :data:`DERIVED` it holds, as CF ancillary variables (``ancillary_variables`` on the variable,
    ``flag_values``/``flag_meanings`` on the flag), in place. Returns the per-variable :func:`flag_summary`."""
    import numpy as np

    flags = {}
    for var in DERIVED:
        c = cfg.derived.get(var)
        if c is None or var not in ds.variables:
            continue
        da = ds[var]
        rng = c.model_copy(update={"spike_suspect": None, "spike_fail": None})  # bins are not a time series
        f = flags_for(da.values, rng).reshape(da.shape)
        ds[f"{var}_qc"] = (da.dims, f, {"long_name": f"QARTOD flag of the binned {var}",
                                        "standard_name": "aggregate_quality_flag",
                                        "flag_values": np.array(list(FLAG_MEANINGS), dtype=np.uint8),
                                        "flag_meanings": " ".join(FLAG_MEANINGS.values()),
                                        "comment": _tests_comment(rng)})
        ds[var].attrs["ancillary_variables"] = f"{var}_qc"  # after the assignment (it may copy the variables)
        flags[f"{var}_qc"] = f
    return flag_summary(flags)


def apply_to_table(df: pd.DataFrame, cfg: DerivedQCConfig, *, latitude_deg: float,
                   longitude_deg: float | None = None) -> dict[str, Any]:
    """Flag a ``ctd`` table in place and return its metadata block (``qc_derived``): ``<var>_qc`` for each
    derived variable; each per-sample input's range flag merged (worst wins) into its ``<input>_qc`` column
    (created when absent, e.g. ``pressure_dbar_qc``); the latitude/longitude flags and the per-variable
    :func:`flag_summary` in the block."""
    import numpy as np
    import pandas as pd

    flags = qc_derived_table(df, cfg, latitude_deg=latitude_deg, longitude_deg=longitude_deg)
    inputs: dict[str, np.ndarray] = {}
    for key in list(flags):
        if key.endswith("_range_qc"):
            name = key[: -len("_range_qc")]
            f = flags.pop(key)
            f = np.where(f == NOT_EVALUATED, GOOD, f).astype(np.uint8)  # the range test was run: pass
            f[~np.isfinite(df[name].to_numpy(np.float64))] = MISSING
            qc = f"{name}_qc"
            if qc in df.columns:
                old = pd.to_numeric(df[qc], errors="coerce").fillna(MISSING).to_numpy().astype(np.uint8)
                f = _worst(old, f)
            df[qc] = f
            inputs[qc] = f
    for k, v in flags.items():
        df[k] = v
    position = {}
    for name, value in (("latitude_deg", latitude_deg), ("longitude_deg", longitude_deg)):
        c = cfg.inputs.get(name)
        if c is not None and value is not None:
            position[name] = {"value": float(value), "flag": int(flags_for([value], c)[0])}
    return {"method": "QARTOD flags (ioos_qc gross range, spike; inputs' range flags inherited), hadal.qc_derived",
            "thresholds": "hadal/data/qc_derived.yaml with derive.qc_thresholds overrides",
            "flag_meanings": {str(k): v for k, v in FLAG_MEANINGS.items()},
            "position": position,
            "summary": flag_summary(flags),
            "inputs": flag_summary(inputs)}
