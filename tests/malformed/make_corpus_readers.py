"""Malformed-input corpus for every reader *other than* the ingest logs (those are in ``make_corpus.py``).

Usage: ``PYTHONPATH=src python tests/malformed/make_corpus_readers.py DEST`` writes ``DEST/<case>/`` (one raw
dive directory per defect) and prints the cases. Readers covered:

* ``soundings``   multibeam XYZ/CSV soundings read by the ``grid`` stage (:func:`hadal.grid.read_soundings`);
* ``point_cloud`` laser PLY / PCD / LAS read by the ``grid`` stage (:func:`hadal.grid.read_point_cloud`);
* ``raster``      GeoTIFF / NetCDF grids (:func:`hadal.grid.read_grid`, library API);
* ``dive_yaml``   ``dive.yaml`` (:func:`hadal.dive.load_dive`, source paths, dive ids);
* ``pipeline_yaml`` the dive's ``pipeline.yaml`` (:func:`hadal.settings.load_config`);
* ``vehicle_yaml`` the vehicle channel mapping (ingest);
* ``upstream``    corrupt products in the store read by a downstream stage (derive, suitability, landing).

A case directory may hold ``_upstream/<product>/<files>``: :func:`publish_upstream` publishes those files as
a version of ``<product>`` in the store *before* the case runs (a product that was written corrupt).
:func:`run_user_path` does what ``hadal stage <stage> DIR --store S`` does, minus Prefect. Each case either
raises a one-line :class:`hadal.errors.HadalError` of the class ``error`` whose message matches ``match``
(the store then must be unchanged), or publishes / returns data for which ``check`` holds (flagged data).
"""

from __future__ import annotations

import gzip
import shutil
import sys
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from affine import Affine

sys.path.insert(0, str(Path(__file__).parent))
from tiny_dive import write_dive  # noqa: E402

DIVE_ID = "malformed-readers"
LAT0, LON0 = 11.3371167, 142.2097167
MB = "multibeam/em122_line01.xyz.gz"
LASER = "laser/submap_01.ply"


@dataclass
class RCase:
    name: str
    reader: str                                   # reader family (see module docstring)
    description: str
    make: Callable[[Path], None]                  # mutates a copy of the base dive directory
    stage: str | tuple[str, ...] | None = "grid"  # stage(s) run on the dive in turn (None: only load dive + config)
    call: Callable[[Path], Any] | None = None     # library reader call instead of a stage
    error: str | None = None                      # expected HadalError subclass (None: must succeed, flagged)
    match: str = ""                               # regex the one-line message must contain
    check: Callable[[Any], bool] | None = None    # for successful cases: the result flags the defect


# ---------------------------------------------------------------------------------------------- base data
def soundings_text(n: int = 6000, seed: int = 1) -> str:
    """``lon lat depth`` lines on smooth terrain in a 600 m square around the launch point."""
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(-300, 300, n), rng.uniform(-300, 300, n)
    depth = 10_900 + 30 * np.sin(x / 150) + 20 * np.cos(y / 120) + rng.normal(0, 0.5, n)
    lon = LON0 + x / (111_320.0 * np.cos(np.radians(LAT0)))
    lat = LAT0 + y / 110_574.0
    return "".join(f"{a:.7f} {b:.7f} {c:.2f}\n" for a, b, c in zip(lon, lat, depth, strict=True))


def laser_points(n: int = 8000, seed: int = 2) -> np.ndarray:
    """A 0.4 m x 0.4 m laser patch (local frame, z up), smooth with 1 mm noise."""
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0, 0.4, n), rng.uniform(0, 0.4, n)
    z = -10_900 + 0.02 * np.sin(x * 20) + 0.01 * np.cos(y * 15) + rng.normal(0, 0.001, n)
    return np.column_stack([x, y, z])


def write_ply(path: Path, pts: np.ndarray, n_declared: int | None = None) -> None:
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {n_declared if n_declared is not None else len(pts)}\n"
            "property double x\nproperty double y\nproperty double z\nend_header\n").encode()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(head + np.ascontiguousarray(pts, dtype="<f8").tobytes())


def write_las(path: Path, pts: np.ndarray) -> None:
    import laspy

    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([0.0001, 0.0001, 0.0001])
    header.offsets = pts.min(axis=0)
    las = laspy.LasData(header)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    path.parent.mkdir(parents=True, exist_ok=True)
    las.write(str(path))


def write_geotiff(path: Path, z: np.ndarray, *, crs: str | None = "EPSG:4326", nodata: float | None = -9999.0,
                  transform=None) -> None:
    import rasterio
    from affine import Affine

    path.parent.mkdir(parents=True, exist_ok=True)
    t = transform if transform is not None else Affine(0.01, 0.0, 142.0, 0.0, -0.01, 11.5)
    with rasterio.open(path, "w", driver="GTiff", height=z.shape[0], width=z.shape[1], count=1, dtype="float32",
                       crs=crs, transform=t, nodata=nodata) as dst:
        dst.write(z.astype(np.float32), 1)


def relief(ny: int = 20, nx: int = 20) -> np.ndarray:
    yy, xx = np.mgrid[0:ny, 0:nx]
    return (-8000.0 - 300 * np.sin(xx / 4.0) - 200 * np.cos(yy / 5.0)).astype(np.float64)


def write_nc(path: Path, z: np.ndarray | None = None, *, name: str = "z", coords: bool = True, **kw) -> None:
    import xarray as xr

    z = relief() if z is None else z
    ny, nx = z.shape
    c = {"lon": ("lon", 142.0 + 0.01 * np.arange(nx), {"units": "degrees_east"}),
         "lat": ("lat", 11.0 + 0.01 * np.arange(ny), {"units": "degrees_north"})} if coords else {}
    path.parent.mkdir(parents=True, exist_ok=True)
    xr.Dataset({name: (("lat", "lon"), z)}, coords=c).to_netcdf(path, engine="h5netcdf", **kw)


# ---------------------------------------------------------------------------------------------- helpers
def _dive_yaml(d: Path, text: str | None = None, **changes) -> None:
    if text is not None:
        (d / "dive.yaml").write_text(text)
        return
    y = yaml.safe_load((d / "dive.yaml").read_text())
    for k, v in changes.items():
        if isinstance(v, dict) and isinstance(y.get(k), dict):
            y[k].update(v)
        else:
            y[k] = v
    (d / "dive.yaml").write_text(yaml.safe_dump(y, sort_keys=False))


def _sources(d: Path, **s) -> None:
    _dive_yaml(d, sources=s)


def _mb(d: Path, text: str | bytes, name: str = "em122_line01.xyz", gz: bool = False) -> None:
    """Replace the multibeam source with one file holding ``text``."""
    p = d / "multibeam" / (name + (".gz" if gz else ""))
    for old in (d / "multibeam").glob("*"):
        old.unlink()
    data = text.encode() if isinstance(text, str) else text
    p.write_bytes(gzip.compress(data) if gz else data)
    _sources(d, multibeam=[f"multibeam/{p.name}"], laser=[])


def _mb_lines(fn: Callable[[list[str]], list[str]]) -> Callable[[Path], None]:
    return lambda d: _mb(d, "\n".join(fn(soundings_text().splitlines())) + "\n")


def _laser(d: Path, name: str, data: bytes | None = None, pts: np.ndarray | None = None, **kw) -> None:
    p = d / "laser" / name
    (d / "laser" / "submap_01.ply").unlink(missing_ok=True)
    if pts is not None and name.endswith(".ply"):
        write_ply(p, pts, **kw)
    elif pts is not None and name.endswith(".las"):
        write_las(p, pts)
    else:
        p.write_bytes(data or b"")
    _sources(d, multibeam=[], laser=[f"laser/{name}"])


def _pts(fn: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
    return fn(laser_points().copy())


def _set(a: np.ndarray, idx, col, value) -> np.ndarray:
    a[idx, col] = value
    return a


def _cfg(d: Path, text: str) -> None:
    (d / "pipeline.yaml").write_text(text)


def _vehicle_edit(fn: Callable[[dict], None]) -> Callable[[Path], None]:
    def f(d: Path) -> None:
        y = yaml.safe_load((d / "vehicle.yaml").read_text())
        fn(y)
        (d / "vehicle.yaml").write_text(yaml.safe_dump(y, sort_keys=False))
    return f


def _upstream(d: Path, product: str, files: dict[str, bytes]) -> None:
    up = d / "_upstream" / product
    up.mkdir(parents=True, exist_ok=True)
    for name, data in files.items():
        (up / name).write_bytes(data)


def _template(d: Path, name: str) -> Path:
    return d.parent / "_templates" / name


def _sensors(fn: Callable[[Any], Any]) -> Callable[[Path], None]:
    """Upstream ``sensors`` product = the valid template table transformed by ``fn`` (written as Parquet)."""
    def f(d: Path) -> None:
        import io

        import pandas as pd

        df = fn(pd.read_parquet(_template(d, "sensors.parquet")))
        buf = io.BytesIO()
        df.to_parquet(buf)
        _upstream(d, "sensors", {"sensors.parquet": buf.getvalue()})
    return f


def _bytes_of(template: str, fn: Callable[[bytes], bytes]) -> Callable[[Path], bytes]:
    return lambda d: fn(_template(d, template).read_bytes())


def _dataset(template: str, fn: Callable[[Any], Any]) -> Callable[[Path], bytes]:
    def f(d: Path) -> bytes:
        import xarray as xr

        with xr.open_dataset(_template(d, template), engine="h5netcdf") as ds:
            out = fn(ds.load())
        tmp = d / "_tmp.nc"
        for v in out.variables.values():
            v.encoding = {}
        out.to_netcdf(tmp, engine="h5netcdf")
        data = tmp.read_bytes()
        tmp.unlink()
        return data
    return f


def _up(product: str, name: str, data: Callable[[Path], bytes]) -> Callable[[Path], None]:
    return lambda d: _upstream(d, product, {name: data(d)})


def _grid_call(name: str, **kw) -> Callable[[Path], Any]:
    def f(d: Path) -> Any:
        from hadal.grid.readers import read_grid

        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            da = read_grid(d / "grids" / name, **kw)
        da.attrs["_warnings"] = [str(w.message) for w in caught]
        return da
    return f


def _manifest_summary(res: dict, product: str = "dtm") -> dict:
    return res[product].manifest().get("summary", {})


def _dtm_depth_median(res: dict) -> float:
    import xarray as xr

    with xr.open_dataset(res["dtm"].file("dtm.nc"), engine="h5netcdf") as ds:
        return float(ds["depth_m"].median())


def _plan_call(d: Path):
    """What `hadal run d` checks first: the plan of the stages the data supports (launch needed by match)."""
    from hadal.pipeline import make_context, stage_plan

    return stage_plan(make_context(d, d / ".store"))


def _laser_attrs(res: dict) -> dict:
    import xarray as xr

    f = next(res["laser_grids"].path.glob("*.nc"))
    with xr.open_dataset(f, engine="h5netcdf") as ds:
        return dict(ds.attrs)


def _ctd(res: dict) -> tuple[Any, dict]:
    import pandas as pd

    from hadal.products import read_parquet_metadata

    path = res["ctd"].file("ctd.parquet")
    return pd.read_parquet(path), read_parquet_metadata(path)[0]


def _profile_time_missing(res: dict) -> bool:
    import xarray as xr

    with xr.open_dataset(res["profile"].file("profile.nc"), engine="h5netcdf") as ds:
        return bool(ds["time"].isnull().all()) and ds.sizes["profile"] == 2


def _half(b: bytes) -> bytes:
    return b[: len(b) // 2]


# ---------------------------------------------------------------------------------------------- cases
S, P, R, D, C, V, U = "soundings", "point_cloud", "raster", "dive_yaml", "pipeline_yaml", "vehicle_yaml", "upstream"

CASES: list[RCase] = [
    # ----- multibeam soundings (grid stage)
    RCase("mb_empty", S, "0-byte soundings file", lambda d: _mb(d, ""), error="InputError", match="is empty"),
    RCase("mb_gzip_truncated", S, "gzip soundings cut in half",
          lambda d: (_mb(d, soundings_text(), gz=True),
                     (p := d / "multibeam" / "em122_line01.xyz.gz").write_bytes(_half(p.read_bytes()))),
          error="InputError", match="corrupt or truncated gzip"),
    RCase("mb_gzip_bitflip", S, "one byte flipped inside the gzip stream",
          lambda d: (_mb(d, soundings_text(), gz=True),
                     (p := d / "multibeam" / "em122_line01.xyz.gz").write_bytes(
                         (lambda b: b[:len(b) // 2] + bytes([b[len(b) // 2] ^ 0xFF]) + b[len(b) // 2 + 1:])(p.read_bytes()))),
          error="InputError", match="corrupt or truncated gzip"),
    RCase("mb_truncated_last_line", S, "plain text cut inside the last line",
          lambda d: _mb(d, soundings_text()[:-12]), error="InputError", match="truncated file"),
    RCase("mb_missing_column", S, "only longitude and latitude",
          _mb_lines(lambda L: [" ".join(x.split()[:2]) for x in L]), error="InputError", match="expected 3 columns"),
    RCase("mb_extra_column", S, "a fourth (backscatter) column: ignored, DTM published",
          _mb_lines(lambda L: [x + " -35.5" for x in L]),
          check=lambda r: _manifest_summary(r)["n_soundings_used"] > 5000),
    RCase("mb_swapped_columns", S, "latitude first (renamed/swapped columns)",
          _mb_lines(lambda L: [" ".join([x.split()[1], x.split()[0], x.split()[2]]) for x in L]),
          error="InputError", match="latitude out of"),
    RCase("mb_elevations", S, "depths given as negative elevations (sign/unit convention)",
          _mb_lines(lambda L: [" ".join(x.split()[:2] + ["-" + x.split()[2]]) for x in L]),
          # all-negative values are elevations: negated (recorded) into depths, never gridded upside down
          check=lambda r: _dtm_depth_median(r) > 10_000),
    RCase("mb_non_numeric", S, "a row with a text depth",
          _mb_lines(lambda L: L[:100] + ["142.2 11.3 deep"] + L[100:]), error="InputError", match="non-numeric depth_m"),
    RCase("mb_header_only", S, "header line and no data",
          lambda d: _mb(d, "longitude latitude depth\n"), error="InputError", match="no soundings"),
    RCase("mb_comments_only", S, "only comment lines",
          lambda d: _mb(d, "# EM122\n# no data\n"), error="InputError", match="no data lines"),
    RCase("mb_binary_garbage", S, "random bytes named .xyz",
          lambda d: _mb(d, np.random.default_rng(5).integers(0, 256, 4000, dtype=np.uint8).tobytes()),
          error="InputError", match="columns|non-numeric|cannot parse|no data|truncated"),
    RCase("mb_nan_inf", S, "NaN and inf depths: dropped and counted",
          _mb_lines(lambda L: [(" ".join(x.split()[:2] + ["nan" if i % 2 else "inf"]) if i % 97 == 0 else x)
                               for i, x in enumerate(L)]),
          check=lambda r: _manifest_summary(r)["n_soundings_nonfinite"] == 62),
    RCase("mb_spikes", S, "20 soundings 2 km too deep (beyond Earth's deepest): rejected as implausible or spikes",
          _mb_lines(lambda L: [(" ".join(x.split()[:2] + [str(float(x.split()[2]) + 2000)]) if i % 300 == 7 else x)
                               for i, x in enumerate(L)]),
          check=lambda r: (_manifest_summary(r)["n_soundings_spikes"]
                           + _manifest_summary(r).get("n_soundings_implausible", 0)) >= 20),
    RCase("mb_gigantic_values", S, "depths of 1e300 m: rejected as implausible, no overflow",
          _mb_lines(lambda L: [(" ".join(x.split()[:2] + ["1e300"]) if i % 500 == 3 else x) for i, x in enumerate(L)]),
          check=lambda r: _manifest_summary(r).get("n_soundings_implausible", 0) == 12),
    RCase("mb_gigantic_extent", S, "one sounding on the far side of the Earth: grid too large",
          _mb_lines(lambda L: L + ["-37.0 -11.0 4000.0"]), error="InputError", match="cells"),
    RCase("mb_missing_file", S, "dive.yaml lists a multibeam file that is not there",
          lambda d: _sources(d, multibeam=["multibeam/nope.xyz.gz"], laser=[]), error="InputError", match="does not exist"),
    RCase("mb_path_escape", S, "multibeam source '../../etc/passwd' escapes the dive directory",
          lambda d: _sources(d, multibeam=["../../etc/passwd"], laser=[]), error="ConfigError", match="escapes the dive"),
    # ----- laser point clouds (grid stage)
    RCase("ply_empty", P, "0-byte PLY", lambda d: _laser(d, "submap_01.ply", b""), error="InputError", match="is empty"),
    RCase("ply_truncated", P, "binary PLY cut in the middle of the vertex data",
          lambda d: (_laser(d, "submap_01.ply", pts=laser_points()),
                     (p := d / "laser" / "submap_01.ply").write_bytes(_half(p.read_bytes()))),
          error="InputError", match="truncated"),
    RCase("ply_header_only", P, "PLY header without vertex data",
          lambda d: (_laser(d, "submap_01.ply", pts=laser_points()),
                     (p := d / "laser" / "submap_01.ply").write_bytes(p.read_bytes()[:200])),
          error="InputError", match="no points read|truncated"),
    RCase("ply_not_ply", P, "text file named .ply", lambda d: _laser(d, "submap_01.ply", b"hello world\n" * 20),
          error="InputError",
          match="no points read|not a PLY|unsupported point cloud format"),
    RCase("ply_nan_points", P, "40 NaN/inf points: dropped and counted",
          lambda d: _laser(d, "submap_01.ply", pts=_pts(lambda a: _set(_set(a, slice(0, 20), 2, np.nan), slice(20, 40), 0, np.inf))),
          check=lambda r: _laser_attrs(r)["n_points_nonfinite"] == 40),
    RCase("ply_all_nan", P, "every point NaN", lambda d: _laser(d, "submap_01.ply", pts=np.full((100, 3), np.nan)),
          error="InputError", match="NaN/inf"),
    RCase("ply_gigantic_extent", P, "one stray point 1e7 m away: removed as an outlier, grid stays 0.4 m",
          lambda d: _laser(d, "submap_01.ply", pts=np.vstack([laser_points(), [[1e7, 1e7, -10_900.0]]])),
          check=lambda r: _laser_attrs(r)["n_points_outliers"] >= 1 and _laser_attrs(r)["n_points_used"] >= 7900),
    RCase("ply_gigantic_extent_dense", P, "two dense patches 1e5 m apart: grid refused before allocating",
          lambda d: _laser(d, "submap_01.ply", pts=np.vstack([laser_points(), laser_points() + [1e5, 1e5, 0]])),
          error="InputError", match="cells"),
    RCase("ply_single_point", P, "a cloud of one point",
          lambda d: _laser(d, "submap_01.ply", pts=laser_points()[:1]), error="InputError", match="point"),
    RCase("pcd_garbage", P, "garbage named .pcd", lambda d: _laser(d, "submap_01.pcd", b"# .PCD v0.7\nFIELDS x y\nDATA ascii\n1 2\n"),
          error="InputError", match="no points read"),
    RCase("las_truncated", P, "LAS file cut in half",
          lambda d: (_laser(d, "submap_01.las", pts=laser_points()),
                     (p := d / "laser" / "submap_01.las").write_bytes(_half(p.read_bytes()))),
          error="InputError",
          match="cannot read LAS|unsupported point cloud format|declares [0-9,]+ points but the file holds"),
    RCase("las_not_las", P, "text file named .las", lambda d: _laser(d, "submap_01.las", b"not a las file\n" * 30),
          error="InputError",
          match="cannot read LAS|unsupported point cloud format"),
    RCase("laser_unsupported_format", P, "laser source with extension .txt",
          lambda d: _laser(d, "submap_01.txt", b"1 2 3\n"), error="InputError", match="unsupported point cloud format"),
    RCase("laser_duplicate_names", P, "two laser sources with the same file name",
          lambda d: ((d / "laser" / "b").mkdir(), shutil.copy(d / LASER, d / "laser" / "b" / "submap_01.ply"),
                     _sources(d, multibeam=[], laser=[LASER, "laser/b/submap_01.ply"])),
          # both analysed, under distinct product file names (never one overwriting the other)
          check=lambda r: len(list(r["laser_grids"].path.glob("*.nc"))) == 2),
    # ----- rasters (library reader read_grid)
    RCase("tif_empty", R, "0-byte GeoTIFF", lambda d: ((d / "grids").mkdir(), (d / "grids" / "g.tif").write_bytes(b"")),
          stage=None, call=_grid_call("g.tif"), error="InputError", match="is empty"),
    RCase("tif_truncated", R, "GeoTIFF cut in half",
          lambda d: (write_geotiff(d / "grids" / "g.tif", relief()),
                     (p := d / "grids" / "g.tif").write_bytes(_half(p.read_bytes()))),
          stage=None, call=_grid_call("g.tif"), error="InputError", match="cannot read (GeoTIFF|raster)|truncated: .* the header implies"),
    RCase("tif_all_nodata", R, "every cell nodata",
          lambda d: write_geotiff(d / "grids" / "g.tif", np.full((10, 10), -9999.0)),
          stage=None, call=_grid_call("g.tif"), error="InputError", match="no valid"),
    RCase("tif_rotated", R, "rotated geotransform",
          lambda d: write_geotiff(d / "grids" / "g.tif", relief(),
                                  transform=Affine(0.01, 0.002, 142.0, 0.002, -0.01, 11.5)),
          stage=None, call=_grid_call("g.tif"), error="InputError", match="rotated"),
    RCase("tif_wrong_crs", R, "metric 20 m laser grid tagged EPSG:4326: flagged local_metric with a warning",
          lambda d: write_geotiff(d / "grids" / "g.tif", -10_900 + 0.01 * relief() / 300,
                                  transform=Affine(1.0, 0.0, 0.0, 0.0, -1.0, 20.0)),
          stage=None, call=_grid_call("g.tif"),
          check=lambda da: da.attrs["crs_kind"] == "local_metric" and "crs_override" in da.attrs and da.attrs["_warnings"]),
    RCase("tif_nan_inf", R, "NaN and inf cells become NaN (nodata)",
          lambda d: write_geotiff(d / "grids" / "g.tif", _set(_set(relief(), 0, slice(0, 5), np.nan), 1, slice(0, 5), np.inf)),
          stage=None, call=_grid_call("g.tif"), check=lambda da: int(np.isnan(da.values).sum()) == 10
          and bool(np.isfinite(da.values).sum() == 390)),
    RCase("nc_truncated", R, "NetCDF cut in half",
          lambda d: (write_nc(d / "grids" / "g.nc"), (p := d / "grids" / "g.nc").write_bytes(_half(p.read_bytes()))),
          stage=None, call=_grid_call("g.nc"), error="InputError", match="cannot read NetCDF|truncated: .* the header implies"),
    RCase("nc_no_2d_variable", R, "NetCDF with only 1-D variables",
          lambda d: __import__("xarray").Dataset({"v": ("n", np.arange(5.0))}).to_netcdf(
              (d / "grids").mkdir() or d / "grids" / "g.nc", engine="h5netcdf"),
          stage=None, call=_grid_call("g.nc"), error="InputError", match="no 2-D variable"),
    RCase("nc_all_nan", R, "every cell NaN", lambda d: write_nc(d / "grids" / "g.nc", np.full((8, 8), np.nan)),
          stage=None, call=_grid_call("g.nc"), error="InputError", match="no valid"),
    RCase("nc_inf_cells", R, "inf cells in a NetCDF grid become NaN like nodata",
          lambda d: write_nc(d / "grids" / "g.nc", _set(relief(), 3, slice(0, 4), np.inf)),
          stage=None, call=_grid_call("g.nc"), check=lambda da: int(np.isnan(da.values).sum()) == 4
          and not np.isinf(da.values).any()),
    RCase("nc_no_coordinates", R, "grid dimensions without coordinate values",
          lambda d: write_nc(d / "grids" / "g.nc", coords=False), stage=None, call=_grid_call("g.nc"),
          error="InputError", match="no coordinate values"),
    RCase("nc_unknown_variable", R, "asked for a variable the file lacks",
          lambda d: write_nc(d / "grids" / "g.nc"), stage=None, call=_grid_call("g.nc", variable="elevation"),
          error="InputError", match="no variable 'elevation'"),
    RCase("grid_unsupported_format", R, "an ESRI ASCII grid (.asc)",
          lambda d: ((d / "grids").mkdir(), (d / "grids" / "g.asc").write_text("ncols 2\nnrows 2\n1 2\n3 4\n")),
          stage=None, call=_grid_call("g.asc"), error="InputError",
          match="unsupported grid format|not a grid format hadal reads"),
    # ----- dive.yaml
    RCase("dive_bad_yaml", D, "dive.yaml is not YAML", lambda d: _dive_yaml(d, "dive_id: [unclosed\n"), stage=None,
          error="ConfigError", match="not valid YAML"),
    RCase("dive_empty", D, "empty dive.yaml", lambda d: _dive_yaml(d, ""), stage=None,
          error="ConfigError", match="expected a mapping"),
    RCase("dive_missing", D, "no dive.yaml", lambda d: (d / "dive.yaml").unlink(), stage=None,
          error="InputError", match="has no dive.yaml"),
    RCase("dive_missing_launch", D, "dive.yaml without launch but with the data for match (needs the launch)",
          lambda d: _dive_yaml(d, launch=None), stage=None, call=_plan_call, error="ConfigError",
          match="(no 'launch'|need a map frame).*match|match.*(launch|map frame)"),
    RCase("dive_bad_type", D, "latitude given as text", lambda d: _dive_yaml(d, launch={"latitude_deg": "eleven north"}),
          stage=None, error="ConfigError", match="latitude_deg"),
    RCase("dive_out_of_range", D, "latitude 100 degrees", lambda d: _dive_yaml(d, launch={"latitude_deg": 100}),
          stage=None, error="ConfigError", match="latitude_deg"),
    RCase("dive_bad_time", D, "launch time 'yesterday'", lambda d: _dive_yaml(d, launch={"time_utc": "yesterday"}),
          stage=None, error="ConfigError", match="time_utc"),
    RCase("dive_unknown_key", D, "misspelt key 'soures'", lambda d: _dive_yaml(d, soures={"mcap": []}),
          stage=None, error="ConfigError", match="soures"),
    RCase("dive_id_traversal", D, "dive_id '../../evil'", lambda d: _dive_yaml(d, dive_id="../../evil"), stage=None,
          error="ConfigError", match="invalid dive id"),
    RCase("dive_id_slash", D, "dive_id with a path separator", lambda d: _dive_yaml(d, dive_id="a/b"), stage=None,
          error="ConfigError", match="invalid dive id"),
    RCase("dive_sources_wrong_type", D, "sources.mcap is a string, not a list",
          lambda d: _dive_yaml(d, sources={"mcap": 5}), stage=None, error="ConfigError", match="sources.mcap"),
    RCase("dive_source_escape", D, "MCAP source '../../../etc/passwd'",
          lambda d: _dive_yaml(d, sources={"mcap": ["../../../etc/passwd"]}), stage="ingest",
          error="ConfigError", match="escapes the dive directory"),
    RCase("dive_source_absolute", D, "absolute CSV source path outside the dive",
          lambda d: _dive_yaml(d, sources={"mcap": [], "csv": {"ctd": "/etc/hostname"}}), stage="ingest",
          error="ConfigError", match="escapes the dive directory"),
    RCase("dive_vehicle_escape", D, "vehicle_config '../vehicle.yaml' outside the dive",
          lambda d: _dive_yaml(d, vehicle_config="../vehicle.yaml"), stage="ingest",
          error="ConfigError", match="escapes the dive directory"),
    RCase("dive_nothing_to_grid", D, "grid stage on a dive with no multibeam or laser sources",
          lambda d: _sources(d, multibeam=[], laser=[]), stage="grid", error="StageError", match="the dive lists no multibeam soundings or prior bathymetry grid"),
    # ----- pipeline.yaml (dive's own configuration)
    RCase("cfg_bad_yaml", C, "pipeline.yaml is not YAML", lambda d: _cfg(d, "grid: {dtm_resolution_m: [\n"), stage=None,
          error="ConfigError", match="not valid YAML"),
    RCase("cfg_not_mapping", C, "pipeline.yaml is a list", lambda d: _cfg(d, "- grid\n- derive\n"), stage=None,
          error="ConfigError", match="expected a mapping"),
    RCase("cfg_unknown_section", C, "unknown stage section", lambda d: _cfg(d, "gridding: {dtm_resolution_m: 5}\n"),
          stage=None, error="ConfigError", match="gridding"),
    RCase("cfg_unknown_key", C, "unknown key in a section", lambda d: _cfg(d, "grid: {dtm_res: 5}\n"), stage=None,
          error="ConfigError", match="grid.dtm_res"),
    RCase("cfg_out_of_range", C, "negative DTM resolution", lambda d: _cfg(d, "grid: {dtm_resolution_m: -5}\n"),
          stage=None, error="ConfigError", match="grid.dtm_resolution_m.*greater than 0"),
    RCase("cfg_nan", C, "NaN DTM resolution", lambda d: _cfg(d, "grid: {dtm_resolution_m: .nan}\n"), stage=None,
          error="ConfigError", match="grid.dtm_resolution_m"),
    RCase("cfg_bad_type", C, "text where a number is expected", lambda d: _cfg(d, "derive: {profile_bin_dbar: ten}\n"),
          stage=None, error="ConfigError", match="derive.profile_bin_dbar"),
    RCase("cfg_bad_window", C, "bias window with low > high",
          lambda d: _cfg(d, "derive: {gauge_bias_window_dbar: [9000, 100]}\n"), stage=None,
          error="ConfigError", match="gauge_bias_window_dbar"),
    RCase("cfg_section_not_mapping", C, "a section given as a scalar", lambda d: _cfg(d, "grid: 5\n"), stage=None,
          error="ConfigError", match="grid"),
    RCase("cfg_tiny_laser_resolution", C, "1 micrometre laser cells: grid refused before allocating",
          lambda d: (_cfg(d, "grid: {laser_resolution_m: 1.0e-6}\n"), _sources(d, multibeam=[], laser=[LASER])),
          error="InputError", match="cells"),
    # ----- vehicle channel mapping
    RCase("vehicle_empty", V, "0-byte vehicle.yaml", lambda d: (d / "vehicle.yaml").write_text(""), stage="ingest",
          error="ConfigError", match="expected a mapping"),
    RCase("vehicle_no_sensors", V, "vehicle.yaml without sensors",
          _vehicle_edit(lambda y: y.pop("sensors")), stage="ingest", error="ConfigError", match="sensors"),
    RCase("vehicle_bad_time_base", V, "time_base names a sensor that is not mapped",
          _vehicle_edit(lambda y: y.update(time_base="sonar")), stage="ingest", error="ConfigError", match="time_base"),
    RCase("vehicle_sensor_without_source", V, "a sensor with neither mcap nor csv mapping",
          _vehicle_edit(lambda y: (y["sensors"]["position"].pop("mcap"), y["sensors"]["position"].pop("csv"))), stage="ingest",
          error="ConfigError", match="'mcap' or a 'csv'"),
    RCase("vehicle_bad_time_format", V, "unknown time format",
          _vehicle_edit(lambda y: y["sensors"]["ctd"]["mcap"]["time"].update(format="fortnights")), stage="ingest",
          error="ConfigError", match="time format"),
    # ----- corrupt upstream products in the store
    RCase("up_sensors_truncated", U, "sensors.parquet cut in half (published corrupt), read by derive",
          _up("sensors", "sensors.parquet", _bytes_of("sensors.parquet", _half)), stage="derive",
          error="InputError", match="cannot read sensors table"),
    RCase("up_sensors_not_parquet", U, "sensors.parquet is CSV text",
          _up("sensors", "sensors.parquet", lambda d: b"time,cond\n1,2\n"), stage="derive",
          error="InputError", match="cannot read sensors table"),
    RCase("up_sensors_missing_file", U, "sensors version without sensors.parquet",
          _up("sensors", "readme.txt", lambda d: b"oops\n"), stage="derive", error="StoreError", match="no file 'sensors.parquet'"),
    RCase("up_sensors_missing_column", U, "sensors table without conductivity",
          _sensors(lambda df: df.drop(columns=["conductivity_s_m"])), stage="derive",
          error="InputError", match="lacks required column.*conductivity_s_m"),
    RCase("up_sensors_no_rows", U, "sensors table with the columns but no rows",
          _sensors(lambda df: df.iloc[:0]), stage="derive", error="InputError", match="no rows|empty|no valid"),
    RCase("up_sensors_no_pressure", U, "every pressure NaN",
          _sensors(lambda df: df.assign(pressure_ctd_dbar=np.nan, pressure_gauge_dbar=np.nan)), stage="derive",
          error="InputError", match="pressure"),
    RCase("up_sensors_shuffled", U, "sensors rows out of time order: derive sorts them",
          _sensors(lambda df: df.sample(frac=1.0, random_state=3)), stage="derive",
          check=lambda r: _ctd(r)[0]["time"].is_monotonic_increasing and len(_ctd(r)[0]) == 320),
    RCase("up_sensors_duplicated_time", U, "30 sensors rows duplicated: dropped and counted",
          _sensors(lambda df: __import__("pandas").concat([df, df.iloc[10:40]])), stage="derive",
          check=lambda r: _ctd(r)[0]["time"].is_unique and _ctd(r)[1]["duplicate_times_dropped"] == 30),
    RCase("up_sensors_gigantic", U, "1e300 conductivities flagged bad (4): no salinity there, finite elsewhere",
          _sensors(lambda df: df.assign(
              conductivity_s_m=np.where(np.arange(len(df)) % 50 == 5, 1e300, df["conductivity_s_m"]),
              conductivity_s_m_qc=np.where(np.arange(len(df)) % 50 == 5, 4, df["conductivity_s_m_qc"]).astype("uint8"))),
          stage="derive", check=lambda r: int(_ctd(r)[0]["practical_salinity"].isna().sum()) == 7
          and bool(np.isfinite(_ctd(r)[0]["depth_m"]).all())),
    RCase("up_sensors_bottom_only", U, "a log that starts and ends on the bottom (no descent/ascent): profile times missing",
          _sensors(lambda df: df), stage=("derive", "profile"), check=lambda r: _profile_time_missing(r)),
    RCase("up_laser_all_nan", U, "laser grid with no mapped cell: skipped with a warning, empty site table",
          _up("laser_grids", "submap_01.nc", _dataset("submap_01.nc", lambda ds: ds.assign(elevation_m=ds["elevation_m"] * np.nan))),
          stage="landing", check=lambda r: len(__import__("pandas").read_parquet(r["landing"].file("landing_sites.parquet"))) == 0),
    RCase("up_dtm_truncated", U, "dtm.nc cut in half, read by suitability",
          _up("dtm", "dtm.nc", _bytes_of("dtm.nc", _half)), stage="suitability", error="InputError", match="cannot read the DTM"),
    RCase("up_dtm_no_depth", U, "dtm.nc without depth_m",
          _up("dtm", "dtm.nc", _dataset("dtm.nc", lambda ds: ds.rename({"depth_m": "elevation"}))), stage="suitability",
          error="InputError", match="no 'depth_m'|no depth_m"),
    RCase("up_dtm_all_nan", U, "dtm.nc whose depths are all NaN",
          _up("dtm", "dtm.nc", _dataset("dtm.nc", lambda ds: ds.assign(depth_m=ds["depth_m"] * np.nan))),
          stage="suitability", error="InputError", match="no finite cells"),
    RCase("up_dtm_one_cell", U, "degenerate 1 x 1 DTM",
          _up("dtm", "dtm.nc", _dataset("dtm.nc", lambda ds: ds.isel(x=slice(0, 1), y=slice(0, 1)))),
          stage="suitability", error="InputError", match="at least 2 x 2"),
    RCase("up_laser_truncated", U, "laser grid submap_01.nc cut in half, read by landing",
          _up("laser_grids", "submap_01.nc", _bytes_of("submap_01.nc", _half)), stage="landing",
          error="InputError", match="cannot read laser grid"),
    RCase("up_laser_no_elevation", U, "laser grid without elevation_m",
          _up("laser_grids", "submap_01.nc", _dataset("submap_01.nc", lambda ds: ds.rename({"elevation_m": "z"}))),
          stage="landing", error="InputError", match="no variable 'elevation_m'"),
    RCase("up_laser_no_submaps", U, "laser_grids version with no submap files",
          _up("laser_grids", "notes.txt", lambda d: b"empty\n"), stage="landing", error="StageError",
          match="no submap_NN.nc|no laser grids"),
    RCase("up_missing_product", U, "derive before ingest: no sensors product at all", lambda d: None, stage="derive",
          error="StageError", match="no 'sensors' product yet"),
]


# ---------------------------------------------------------------------------------------------- runner
def publish_upstream(d: Path, store_root: Path) -> None:
    """Publish ``d/_upstream/<product>/*`` as one version of each product (a corrupt product already in the store)."""
    from hadal.store import ProductStore

    up = d / "_upstream"
    if not up.is_dir():
        return
    store = ProductStore(store_root)
    dive_id = yaml.safe_load((d / "dive.yaml").read_text())["dive_id"]
    for pdir in sorted(up.iterdir()):
        with store.publish(dive_id, pdir.name, parameters={"corpus": "corrupt upstream"}) as draft:
            for f in pdir.iterdir():
                shutil.copy(f, draft.path / f.name)


def run_user_path(case: RCase, d: Path, store_root: Path, config=None) -> Any:
    """What ``hadal stage <case.stage> d --store store_root`` runs, without Prefect (``case.call`` for library readers)."""
    from hadal.pipeline import make_context, run_stage
    from hadal.stages.plan import resolve_stages

    if case.call is not None:
        return case.call(d)
    ctx = make_context(d, store_root, config)  # the CLI's fail-fast validation: dive.yaml + pipeline.yaml
    if case.stage is None:
        return ctx
    out: dict[str, Any] = {}
    for stage in (case.stage if isinstance(case.stage, tuple) else (case.stage,)):  # a tuple: stages in turn
        names = resolve_stages([stage])
        name = names[0] if len(names) == 1 else stage  # a group (grid = dtm + laser) runs what the dive supports
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out.update(run_stage(name, ctx))
    return out


def _make_templates(dest: Path, base: Path) -> None:
    """Valid ``sensors.parquet``, ``dtm.nc`` and ``submap_01.nc`` made by the real stages from the base dive."""
    from hadal.pipeline import make_context, run_stage

    tdir = dest / "_templates"
    if tdir.exists():
        shutil.rmtree(tdir)
    tdir.mkdir(parents=True)
    store = dest / "_template_store"
    if store.exists():
        shutil.rmtree(store)
    ctx = make_context(base, store)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = {**run_stage("ingest", ctx), **run_stage("grid", ctx)}
    shutil.copy(out["sensors"].file("sensors.parquet"), tdir / "sensors.parquet")
    shutil.copy(out["dtm"].file("dtm.nc"), tdir / "dtm.nc")
    shutil.copy(out["laser_grids"].file("submap_01.nc"), tdir / "submap_01.nc")
    shutil.rmtree(store)


def write_base(dest: Path) -> Path:
    """The tiny ingest dive plus one multibeam file and one laser submap (what every case starts from)."""
    base = write_dive(dest, 20.0, dive_id=DIVE_ID)
    (base / "multibeam").mkdir(exist_ok=True)
    (base / MB).write_bytes(gzip.compress(soundings_text().encode()))
    write_ply(base / LASER, laser_points())
    _sources(base, mcap=["logs/haidou.mcap"], csv=yaml.safe_load((base / "dive.yaml").read_text())["sources"]["csv"],
             multibeam=[MB], laser=[LASER])
    return base


def build_corpus(dest: str | Path) -> list[tuple[RCase, Path]]:
    """Write every case's dive directory under ``dest``; returns (case, directory) pairs."""
    dest = Path(dest)
    base = write_base(dest / "_base_readers")
    _make_templates(dest, base)
    out = []
    for case in CASES:
        d = dest / case.name
        if d.exists():
            shutil.rmtree(d)
        shutil.copytree(base, d)
        case.make(d)
        out.append((case, d))
    return out


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: make_corpus_readers.py DEST")
    for c, _d in build_corpus(sys.argv[1]):
        print(f"{c.name:30s} {c.reader:14s} {'-> ' + c.error if c.error else '-> succeeds, flagged':24s} {c.description}")
    print(f"{len(CASES)} cases")
