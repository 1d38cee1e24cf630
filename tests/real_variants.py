"""Variants of the dives-real kinds that other users' files take (issue 43, held-back kinds), generated from the
real files with independent libraries (laspy, pypcd4, netCDF4, rasterio) or by rewriting the Sea-Bird/Slocum text
the way SeaSoft / dbd2asc write it. Each builder: ``(shared_data, out_dir) -> Path`` of the new file; nothing is
committed as a binary. Used by tests/realdata/test_real_variants.py (and by a probe over every variant)."""

from __future__ import annotations

import bz2
import re
from pathlib import Path

import numpy as np

# ------------------------------------------------------------------ Sea-Bird .cnv


def _cnv_split(text: str) -> tuple[list[str], list[str]]:
    lines = text.splitlines()
    end = next(i for i, ln in enumerate(lines) if ln.startswith("*END*"))
    return lines[:end + 1], [ln for ln in lines[end + 1:] if ln.strip()]


def _cnv_columns(head: list[str]) -> list[tuple[str, str]]:
    """(short name, full '# name' text after '=') of every column."""
    out = []
    for ln in head:
        m = re.match(r"# name (\d+) = ([^:]+):(.*)$", ln)
        if m:
            out.append((m.group(2).strip(), ln.split("=", 1)[1].strip()))
    return out


def cnv_rewrite(src: Path, dst: Path, *, rename: dict[str, tuple[str, str, float]] | None = None,
                order: list[str] | None = None, drop: tuple[str, ...] = (), nmea: bool | None = None,
                add_nmea: tuple[str, str] | None = None) -> Path:
    """A .cnv rewritten as SeaSoft would have written other channel choices: ``rename`` {old: (new name, new
    long-name text, factor)} multiplies the values by ``factor``; ``order`` the new column order (short names);
    ``drop`` columns left out; ``nmea=False`` removes the NMEA/`** Latitude` position lines; ``add_nmea`` adds
    ``* NMEA Latitude/Longitude`` lines. ``# nquan``, ``# name i``, ``# span i`` are rewritten to match."""
    raw = src.read_bytes()
    text = (bz2.decompress(raw) if raw[:3] == b"BZh" else raw).decode("latin-1")
    head, data = _cnv_split(text)
    cols = _cnv_columns(head)
    names = [c[0] for c in cols]
    spans = [ln for ln in head if re.match(r"# span \d+ =", ln)]
    rows = np.array([ln.split() for ln in data], dtype=object)
    keep = [n for n in (order or names) if n not in drop]
    idx = [names.index(n) for n in keep]
    rename = rename or {}
    new_cols, new_spans, new_data = [], [], []
    for j, i in enumerate(idx):
        n, full = cols[i]
        vals = rows[:, i]
        if n in rename:
            nn, long, f = rename[n]
            full = f"{nn}: {long}"
            if f != 1:
                vals = np.array([f"{float(v) * f:.6e}" for v in vals], dtype=object)
        new_cols.append(f"# name {j} = {full}")
        if spans:
            fv = np.array([float(v) for v in vals])
            new_spans.append(f"# span {j} = {fv.min():.6e}, {fv.max():.6e}")
        new_data.append(vals)
    out_head = []
    for ln in head:
        if re.match(r"# (name|span) \d+ =", ln):
            continue
        if nmea is False and re.match(r"(\* NMEA (Latitude|Longitude)|\*\* (Latitude|Longitude))", ln, re.I):
            continue
        if ln.startswith("# nquan"):
            ln = f"# nquan = {len(idx)}"
        if ln.startswith("# nvalues"):
            out_head.append(ln)
            continue
        if ln.startswith("*END*"):
            out_head += new_cols + new_spans
        out_head.append(ln)
    if add_nmea:
        k = next(i for i, ln in enumerate(out_head) if ln.startswith("* "))
        out_head[k + 1:k + 1] = [f"* NMEA Latitude = {add_nmea[0]}", f"* NMEA Longitude = {add_nmea[1]}"]
    body = ["".join(f"{v:>13s}" for v in r) for r in zip(*new_data, strict=True)]
    dst.write_bytes(("\r\n".join(out_head + body) + "\r\n").encode("latin-1"))
    return dst


def cnv_02dk_renamed(shared: Path, out: Path) -> Path:
    """Binned SBE 9 cast (02dk) as a strain-gauge SBE 19plus names it: prdM, tv290C, c0S/m (S/m = mS/cm / 10),
    no NMEA position (depSM still there), columns reordered."""
    src = shared / "ctd-real/oceissues644_02dk.cnv"
    order = ["tv290C", "c0S/m", "prdM"]
    names = [c[0] for c in _cnv_columns(_cnv_split(src.read_text("latin-1"))[0])]
    rn = {"prDM": ("prdM", "Pressure, Strain Gauge [db]", 1.0),
          "t090C": ("tv290C", "Temperature [ITS-90, deg C]", 1.0),
          "c0mS/cm": ("c0S/m", "Conductivity [S/m]", 0.1)}
    inv = {v[0]: k for k, v in rn.items()}
    return cnv_rewrite(src, out / "02dk_sg_no_nmea.cnv", rename=rn, nmea=False,
                       order=[inv[o] for o in order] + [n for n in names if n not in inv.values()])


def cnv_02dk_microsiemens(shared: Path, out: Path) -> Path:
    """The same cast with conductivity in uS/cm (c0uS/cm), the second sensor pair and salinities dropped."""
    src = shared / "ctd-real/oceissues644_02dk.cnv"
    return cnv_rewrite(src, out / "02dk_uS.cnv", rename={"c0mS/cm": ("c0uS/cm", "Conductivity [uS/cm]", 1000.0)},
                       drop=("t190C", "c1mS/cm", "sal00", "sal11", "potemp090C", "sigma-\xe900", "svCM"))


def cnv_sbe19_unbinned_nmea(shared: Path, out: Path) -> Path:
    """An unbinned 4 Hz SBE 19plus cast (timeS, c0mS/cm, prdM, tv290C) with an NMEA position added, conductivity
    renamed c0S/m (values / 10)."""
    src = shared / "formats-real/sbs_SBE19plus_01906398_2019_07_15_0033_cropped.cnv"
    return cnv_rewrite(src, out / "sbe19_Sm_nmea.cnv", rename={"c0mS/cm": ("c0S/m", "Conductivity [S/m]", 0.1)},
                       add_nmea=("49 05.00 N", "123 30.00 W"))


def cnv_sta0860_oxygen_fluor(shared: Path, out: Path) -> Path:
    """An SBE 9 cast with oxygen (sbeox0ML/L) and a WET Labs ECO fluorometer named flECO-AFL (flCUVA renamed),
    ITS-68 temperature."""
    src = shared / "ctd-real/seabird_sta0860.cnv"
    return cnv_rewrite(src, out / "sta0860_eco.cnv",
                       rename={"flCUVA": ("flECO-AFL", "Fluorescence, WET Labs ECO-AFL/FL [mg/m^3]", 1.0)})


def tsg_header_position_only(shared: Path, out: Path) -> Path:
    """The SBE 21 thermosalinograph without its per-scan latitude/longitude columns: only the NMEA header position."""
    src = shared / "dives-real/seabird_SBE21_TSG_PIR_010.cnv"
    return cnv_rewrite(src, out / "tsg_header_pos.cnv", drop=("latitude", "longitude"))


def slocum_other_sensors(shared: Path, out: Path) -> Path:
    """The Slocum dbd2asc file with another sensor set: no m_altitude, no sci_water_pressure (m_depth remains), columns
    reversed; header ``sensors_per_cycle`` and the names/units/bytes lines rewritten to match."""
    src = shared / "dives-real/gutils_usf_bass_2016_252_1_14_sbd.dat"
    lines = src.read_text("latin-1").splitlines()
    nh = int(next(ln for ln in lines if ln.startswith("num_ascii_tags")).split(":")[1])
    names, units, sizes = lines[nh].split(), lines[nh + 1].split(), lines[nh + 2].split()
    keep = [i for i, n in enumerate(names) if n not in ("m_altitude", "sci_water_pressure")][::-1]
    head = [f"sensors_per_cycle: {len(keep)}" if ln.startswith("sensors_per_cycle") else ln for ln in lines[:nh]]
    rows = [ln.split() for ln in lines[nh + 3:] if ln.strip()]
    body = [" ".join(r[i] for i in keep) + " " for r in rows]
    tri = [" ".join(x[i] for i in keep) + " " for x in (names, units, sizes)]
    p = out / "usf_bass_other_sensors_sbd.dat"
    p.write_text("\n".join(head + tri + body) + "\n", encoding="latin-1")
    return p


# ------------------------------------------------------------------ point clouds (laspy, pypcd4)


def las_variant(shared: Path, out: Path, *, version: str, point_format: int, scale: float, offset_shift: float,
                laz: bool = False, feet: bool = False) -> Path:
    """The Autzen LAS (NAD83 / UTM 10N, m) written by laspy as another LAS version/point format/scale/offset; with
    ``feet`` reprojected (pyproj) to NAD83(HARN) / Oregon GIC Lambert (ft) EPSG:2994 with z in international feet."""
    import laspy
    from pyproj import CRS, Transformer

    src = laspy.read(shared / "dives-real/pdal_autzen-utm.las")
    x, y, z = np.asarray(src.x), np.asarray(src.y), np.asarray(src.z)
    crs = src.header.parse_crs() or CRS.from_epsg(26910)
    if feet:
        crs_out = CRS.from_epsg(2994)
        x, y = Transformer.from_crs(crs, crs_out, always_xy=True).transform(x, y)
        z = z / 0.3048
    else:
        crs_out = crs
    hdr = laspy.LasHeader(version=version, point_format=point_format)
    hdr.scales = np.array([scale, scale, scale])
    hdr.offsets = np.array([np.floor(x.min()) + offset_shift, np.floor(y.min()) - offset_shift, offset_shift])
    hdr.add_crs(crs_out)
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = x, y, z
    las.intensity = np.asarray(src.intensity)
    name = f"autzen_{version.replace('.', '')}_pf{point_format}{'_ft' if feet else ''}.{'laz' if laz else 'las'}"
    las.write(out / name)
    return out / name


def pcd_variant(shared: Path, out: Path, *, encoding: str, upper: bool) -> Path:
    """The Autzen PCD's x/y/z (read with pypcd4) written by pypcd4 as ``ascii``/``binary``/``binary_compressed``
    with lower- or upper-case field names."""
    from pypcd4 import Encoding, PointCloud

    pc = PointCloud.from_path(shared / "dives-real/pdal_autzen-utm.pcd")
    arr = pc.numpy(("X", "Y", "Z"))
    fields = ("X", "Y", "Z") if upper else ("x", "y", "z")
    new = PointCloud.from_points(arr.astype(np.float64), fields, (np.float64, np.float64, np.float64))
    p = out / f"autzen_{encoding}_{'upper' if upper else 'lower'}.pcd"
    new.save(p, encoding=Encoding(encoding))
    return p


# ------------------------------------------------------------------ grids (netCDF4, rasterio)


def nc_grid_variant(shared: Path, out: Path, *, positive: str, units: str, lon0_360: float) -> Path:
    """The Hawaii 4' topography (km, 0-360) written by netCDF4 as a CF grid with ``positive`` up (elevation) or down
    (depth = -elevation), in ``units`` km or m, longitudes starting at ``lon0_360`` in 0-360 (crossing 180 when
    it is below 180 and the grid wider than 180 - lon0)."""
    import netCDF4

    with netCDF4.Dataset(shared / "dives-real/gmt_HI_topo_04.nc") as src:
        zname = next(v for v in src.variables if src.variables[v].ndim == 2)
        z_km = np.asarray(src.variables[zname][:], dtype=np.float64)
        lon = np.asarray(src.variables["lon"][:] if "lon" in src.variables else src.variables["x"][:], float)
        lat = np.asarray(src.variables["lat"][:] if "lat" in src.variables else src.variables["y"][:], float)
    lon = lon - lon[0] + lon0_360
    val = z_km if positive == "up" else -z_km
    if units == "m":
        val = val * 1000.0
    p = out / f"hi_{positive}_{units}_{int(lon0_360)}.nc"
    with netCDF4.Dataset(p, "w") as ds:
        ds.Conventions = "CF-1.8"
        ds.createDimension("lat", lat.size)
        ds.createDimension("lon", lon.size)
        v = ds.createVariable("lat", "f8", ("lat",))
        v[:], v.units, v.standard_name = lat, "degrees_north", "latitude"
        v = ds.createVariable("lon", "f8", ("lon",))
        v[:], v.units, v.standard_name = lon, "degrees_east", "longitude"
        v = ds.createVariable("z", "f4", ("lat", "lon"), fill_value=np.float32(-99999.0))
        v[:] = val.astype(np.float32)
        v.units, v.positive = units, positive
        v.standard_name = "height_above_reference_ellipsoid" if positive == "up" else "depth"
        v.long_name = "elevation" if positive == "up" else "depth"
    return p


def geotiff_projected(shared: Path, out: Path) -> Path:
    """The Kilauea UTM 5N elevations (GMT netCDF, read with netCDF4) lowered by 2000 m (a seafloor) and written by
    rasterio as a GeoTIFF in EPSG:32605 with nodata -9999."""
    import netCDF4
    import rasterio
    from rasterio.transform import from_origin

    with netCDF4.Dataset(shared / "dives-real/gmt_Kilauea.utm.nc") as src:
        zname = next(v for v in src.variables if src.variables[v].ndim == 2)
        z = np.ma.filled(np.ma.asarray(src.variables[zname][:], dtype=np.float64), np.nan)  # _FillValue -> NaN
        xs = np.asarray(src.variables["x"][:], float)
        ys = np.asarray(src.variables["y"][:], float)
    if ys[1] > ys[0]:
        ys, z = ys[::-1], z[::-1]
    h = float(xs[1] - xs[0])
    z = np.where(np.isfinite(z), z - 2000.0, -9999.0).astype(np.float32)
    p = out / "kilauea_seafloor_utm5n.tif"
    with rasterio.open(p, "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1, dtype="float32",
                       crs="EPSG:32605", transform=from_origin(xs[0] - h / 2, ys[0] + h / 2, h, h), nodata=-9999.0) as ds:
        ds.write(z, 1)
    return p


def seaexplorer_legato(shared: Path, out: Path) -> tuple[Path, Path]:
    """The SeaExplorer pair with an RBR Legato payload instead of the GPCTD (as SeaExplorers carry either):
    ``LEGATO_CONDUCTIVITY`` in mS/cm (S/m x 10), ``LEGATO_TEMPERATURE``, ``LEGATO_PRESSURE``; the navigation file
    unchanged. Same ``;`` layout, same fill value 9999."""
    nav = shared / "dives-real/pyglider_sea035.12.gli.sub.36"
    pld = shared / "dives-real/pyglider_sea035.12.pld1.sub.36"
    lines = pld.read_text("latin-1").splitlines()
    head = lines[0].split(";")
    ic = head.index("GPCTD_CONDUCTIVITY")
    rows = []
    for ln in lines[1:]:
        f = ln.split(";")
        if len(f) > ic and f[ic] not in ("", "9999.00", "9999"):
            f[ic] = f"{float(f[ic]) * 10:.5f}"
        rows.append(";".join(f))
    head = [h.replace("GPCTD_", "LEGATO_") if h != "GPCTD_DOF" else h for h in head]
    out_pld = out / pld.name.replace("sea035", "sea099")
    out_pld.write_text("\n".join([";".join(head), *rows]) + "\n", encoding="latin-1")
    out_nav = out / nav.name.replace("sea035", "sea099")
    out_nav.write_bytes(nav.read_bytes())
    return out_nav, out_pld
