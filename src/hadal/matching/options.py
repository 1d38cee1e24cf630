"""Options of the terrain matching, declared once; pydantic only, so :class:`hadal.stages.match.Params` (which
extends them) and :mod:`hadal.products.navigation` load without the NumPy/SciPy search.

* :class:`TercomOptions` -- :func:`hadal.matching.tercom` (criterion, bias, feasibility, second optimum,
  precision), its reference loop :func:`hadal.matching.tercom_direct` and :func:`hadal.matching.refine_tercom`
  (seeds, scale range);
* :class:`DeadReckoningOptions` -- the dead-reckoning error model of the fix uncertainty
  (:func:`hadal.matching.budget.uncertainty_budget`; the posterior fix's random walk,
  :func:`hadal.matching.posterior.posterior_fix`) and of the ``navigation`` product
  (:func:`hadal.products.navigation.navigation_table`);
* :class:`PosteriorNoiseOptions` -- the posterior fix's model of the residuals' along-track correlation;
* :class:`SearchEdgeOptions` -- widen-and-retry and the flag of a fix at the edge of its search (TERCOM, posterior,
  MRF).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class TercomOptions(BaseModel):
    """Options of :func:`tercom` and :func:`refine_tercom`, declared once: the ``match`` stage's ``Params``
    extends this model; the functions take it (``options=``) or its fields as keywords."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    criterion: Literal["msd", "mad", "cor"] = Field("msd", description="TERCOM criterion (paper Eqs. 15-17); the paper uses MSD")
    estimate_bias: bool = Field(True, description="estimate a constant map-minus-measured depth bias at every offset")
    precision: Literal["double", "mixed"] = Field(
        "mixed", description="heading search: float32 screening of every heading + exact float64 check of the best 3 (mixed), or float64 throughout"
    )
    min_valid_fraction: float = Field(0.8, gt=0, le=1, description="minimum fraction of profile samples on valid map cells")
    exclusion_radius_m: float | None = Field(None, gt=0, le=10_000_000, description="neighbourhood (m) excluded when looking for the second optimum (default max(5 cells, 100 m))")
    mismatch_ratio: float = Field(1.2, ge=1, le=1000, description="warn when second-best / best MSD is below this ratio")
    refine_scale_range: float = Field(0.05, ge=0, lt=0.5, description="refinement: DR track scale searched within 1 +- this")
    refine_seeds: int = Field(12, ge=1, le=100, description="refinement: number of distinct coarse minima refined")


#: the :class:`TercomOptions` fields :func:`tercom`, :func:`tercom_direct` and :func:`refine_tercom` take
TERCOM_FIELDS = ("criterion", "estimate_bias", "precision", "min_valid_fraction", "exclusion_radius_m", "mismatch_ratio")
DIRECT_FIELDS = ("criterion", "estimate_bias", "min_valid_fraction")
REFINE_FIELDS = ("estimate_bias", "min_valid_fraction", "exclusion_radius_m", "mismatch_ratio", "refine_scale_range",
                 "refine_seeds")


class DeadReckoningOptions(BaseModel):
    """The dead-reckoning error model, declared once (the ``match`` stage's ``Params`` extends this model; the
    ``navigation`` product reads its defaults here)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    dr_error_fraction: float = Field(
        0.02, ge=0, lt=1,
        description="dead-reckoning error per distance dead-reckoned (1 sigma radial), for the fix uncertainty (the start is carried from where the terrain fixes the track) and the navigation product; "
                    "0.02: the DR-only error grown along the sample dive's bottom track is 1.2-2.3 % (median 1.6 %) of the distance on 10 generator seeds (bench/dr_uncertainty_tercom.py; compass bias 1-2.5 deg, speed scale 1-3 %)",
    )
    drift_random_walk_m_per_sqrt_s: float = Field(
        0.07, ge=0, le=100,
        description="posterior: the dead reckoning's random walk beyond the drift segments, 1-sigma per axis per sqrt(s) (from the navigation's specification: a velocity noise sigma_v correlated over tau_c gives sqrt(2 sigma_v^2 tau_c)); "
                    "it widens the main mode's covariance by the error carried from the terrain that fixes the track to the start. 0.07: 3 mm/s correlated over 5 min, the sample dive's DVL; 0: none",
    )
    dr_unreferenced_drift_m_per_sqrt_s: float = Field(
        5.6, ge=0, le=1000,
        description="navigation product without a match: while the dead reckoning has no velocity reference (unpowered descent and ascent, DR held) the vehicle drifts with the currents; "
                    "1-sigma radial error = this x sqrt(unreferenced seconds), a random walk (currents change with depth). 5.6: the TERCOM paper's 533 m descent drift in 3 h 35 min taken as the median "
                    "of a Rayleigh distribution (533 / sqrt(ln 2 x 12 900 s))",
    )


class PosteriorNoiseOptions(BaseModel):
    """The posterior fix's model of the residuals' along-track correlation
    (:func:`hadal.matching.posterior.posterior_fix`, module docstring *Correlated residuals*), declared once."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    correlation_model: Literal["hac", "acf", "ar1"] = Field(
        "hac",
        description="residual correlation along the track: 'hac' = the main mode's covariance is the HAC sandwich with the "
                    "residuals' autocorrelation (Geyer's initial positive sequence), the likelihood tempered as before; "
                    "'acf' = the same and the likelihood tempered by the effective sample size n / (1 + 2 sum rho_k); "
                    "'ar1' = the previous model (lag-1 AR(1) equivalent n (1 - rho) / (1 + rho), tempered Laplace covariance)",
    )
    correlation_max_lag: int = Field(
        50, ge=1, le=10_000, description="largest lag (samples) of the residual autocorrelation sum (also at most n / 4)")


class SearchEdgeOptions(BaseModel):
    """What happens when a terrain fix sits at the edge of its search (issue 47), declared once: the TERCOM/posterior
    heading or scale at a bound of its search, the MRF coarse optimum within ``mrf_edge_cells`` of its search radius.
    The search is widened once (``edge_widen_factor``, capped) and, if still at the edge, the fix is flagged
    (mismatch ``at_search_edge``, a named warning): its covariance is not a confident fix's."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    edge_retry: bool = Field(True, description="widen a search whose optimum sits at its edge once and search again")
    edge_widen_factor: float = Field(2.0, gt=1, le=5, description="the retry's search half-range = this x the first one (capped below)")
    edge_max_heading_range_deg: float = Field(30.0, gt=0, le=45, description="largest heading half-range of the retry, degrees")
    edge_max_scale_range: float = Field(0.2, gt=0, lt=0.5, description="largest scale half-range of the retry (1 +- this)")
    mrf_edge_cells: float = Field(1.0, ge=0, le=10, description="MRF: a coarse optimum within this many cells of the search radius is at the edge")
    mrf_edge_max_radius_cells: float = Field(60.0, gt=0, le=200, description="MRF: largest search radius of the retry, cells")


#: the :class:`SearchEdgeOptions` fields :func:`hadal.matching.mrf.mrf_refine` takes
MRF_EDGE_FIELDS = ("edge_retry", "edge_widen_factor", "mrf_edge_cells", "mrf_edge_max_radius_cells")


def tercom_options(options: TercomOptions | None, values: dict, allowed: tuple[str, ...], what: str) -> TercomOptions:
    """``options`` (default :class:`TercomOptions`) with the keyword ``values`` (fields in ``allowed``) applied;
    an unknown keyword is a ``TypeError``, a value out of bounds a one-line :class:`hadal.errors.InputError`."""
    from pydantic import ValidationError

    from hadal.errors import InputError, first_validation_error

    unknown = sorted(set(values) - set(allowed))
    if unknown:
        raise TypeError(f"{what}() got unexpected keyword argument(s) {', '.join(map(repr, unknown))}")
    if isinstance(values.get("criterion"), str):
        values = {**values, "criterion": values["criterion"].lower()}
    base = options.model_dump(include=set(TercomOptions.model_fields)) if options is not None else {}
    try:
        return TercomOptions(**{**base, **values})
    except ValidationError as exc:
        loc, msg, _ = first_validation_error(exc)
        raise InputError(f"TERCOM option {loc}={exc.errors()[0].get('input')!r}: {msg}") from None
