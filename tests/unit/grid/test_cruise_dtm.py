"""The cruise DTM (issue 48): several dives' multibeam soundings gridded together, dive by dive and tile by tile
(hadal.grid.cruise), run serially here. Oracle: the in-memory ``grid_multibeam`` of all the soundings, read back
from the files with numpy's own text reader, projected with pyproj into a transverse Mercator frame built here
from the launch points, concatenated in dive order."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest
import yaml

#: launch points (lat, lon) of the synthetic dives, a few km apart in the Challenger Deep
LAUNCHES = [(11.330, 142.200), (11.345, 142.215), (11.322, 142.228)]


def write_cruise_dive(raw: Path, dive_id: str, launch: tuple[float, float], seed: int, n: int = 15_000,
                      lines: int = 2, extra_sources: list[str] | None = None, spikes: float = 0.0) -> Path:
    """A dive directory with ``lines`` gzip xyz multibeam files (lon lat depth) around ``launch``: a sloping
    seafloor with ripples, noise 1 m; a share ``spikes`` of the soundings 30-200 m off."""
    from hadal.geo import LocalFrame

    rng = np.random.default_rng(seed)
    fr = LocalFrame(*launch)
    (raw / "multibeam").mkdir(parents=True, exist_ok=True)
    files = []
    for line in range(1, lines + 1):
        x = rng.uniform(-900, 900, n)
        y = rng.uniform(-700 + 500 * line, -200 + 500 * line, n)
        lon, lat = fr.to_lonlat(x, y)
        z = 10_800 + 0.02 * x + 5 * np.sin(x / 150) + rng.normal(0, 1.0, n)
        if spikes:
            sp = rng.random(n) < spikes
            z[sp] += rng.choice([-1.0, 1.0], sp.sum()) * rng.uniform(30, 200, sp.sum())
        rel = f"multibeam/em124_{dive_id}_l{line}.xyz.gz"
        with gzip.open(raw / rel, "wt") as fh:
            np.savetxt(fh, np.column_stack([lon, lat, z]), fmt="%.8f %.8f %.3f")
        files.append(rel)
    dive = {"dive_id": dive_id, "platform": "test",
            "launch": {"latitude_deg": launch[0], "longitude_deg": launch[1]},
            "sources": {"multibeam": files + list(extra_sources or [])}}
    (raw / "dive.yaml").write_text(yaml.safe_dump(dive))
    return raw


def make_cruise(root: Path, n: int = 15_000) -> list[Path]:
    return [write_cruise_dive(root / f"dive-{k}", f"D{k:03d}", la, seed=k, n=n) for k, la in enumerate(LAUNCHES)]


def oracle_dtm(raws: list[Path], resolution_m: float, launches=LAUNCHES, **kw):
    """grid_multibeam of all the soundings (np.loadtxt of every listed existing file, pyproj into the frame centred
    on the launch points' bounding box), with its default spike test (``kw``: its other arguments)."""
    from pyproj import Transformer

    from hadal.grid.multibeam import grid_multibeam

    lats = [la for la, _ in launches]
    lons = [lo for _, lo in launches]
    lat0, lon0 = (min(lats) + max(lats)) / 2, (min(lons) + max(lons)) / 2
    tm = Transformer.from_crs("EPSG:4326", f"+proj=tmerc +lat_0={lat0!r} +lon_0={lon0!r} +k=1 +x_0=0 +y_0=0 "
                              "+datum=WGS84 +units=m +no_defs", always_xy=True)
    cols = []
    for raw in raws:
        for rel in yaml.safe_load((raw / "dive.yaml").read_text())["sources"]["multibeam"]:
            if (raw / rel).is_file():
                cols.append(np.loadtxt(raw / rel))
    a = np.concatenate(cols)
    x, y = tm.transform(a[:, 0], a[:, 1])
    return grid_multibeam(x, y, a[:, 2], resolution_m, **kw), (lat0, lon0)


def assert_same_dtm(ds, ref) -> None:
    assert ds.sizes == ref.sizes
    np.testing.assert_array_equal(ds["x"].values, ref["x"].values)
    np.testing.assert_array_equal(ds["y"].values, ref["y"].values)
    for v in ("count", "filled"):
        np.testing.assert_array_equal(ds[v].values, ref[v].values)
    for v in ("depth_m", "depth_median_m", "depth_std_m", "uncertainty_m"):
        # the soundings are projected by the same pyproj transform: identical up to its last-bit reproducibility
        np.testing.assert_allclose(ds[v].values, ref[v].values, rtol=0, atol=1e-9, equal_nan=True)
    for k in ("n_soundings_used", "n_soundings_spikes", "spike_noise_floor_m", "spike_filter"):
        np.testing.assert_equal(ds.attrs[k], ref.attrs[k], err_msg=k)  # NaN == NaN here


def test_cruise_dtm_equals_in_memory_grid_of_all_soundings(tmp_path):
    from hadal.grid.cruise import cruise_dtm_dataset, group_tiles

    assert group_tiles([0, 1, 2, 5], [3, 3, 9, 1], 5) == [[0, 1], [2], [5]]  # by hand
    assert group_tiles([0, 1], [3, 3], 1) == [[0], [1]]
    raws = make_cruise(tmp_path / "raw")
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    # small tiles, grouped by about 5000 soundings a task: many units of work, seams between tiles and dives
    ds, prov = cruise_dtm_dataset([str(r) for r in raws], 20.0, scratch, tile_cells=16, min_task_points=5000)
    ref, (lat0, lon0) = oracle_dtm(raws, 20.0)
    assert ds.attrs["n_tiles"] > 4  # seams between tiles and between dives
    assert_same_dtm(ds, ref)
    assert prov["cruise_frame"]["origin_latitude_deg"] == pytest.approx(lat0, abs=1e-9)
    assert prov["cruise_frame"]["origin_longitude_deg"] == pytest.approx(lon0, abs=1e-9)
    assert all(d["used"] and len(d["files_used"]) == 2 for d in prov["dives"].values())
    assert ds.attrs["cruise_dives"] == "D000, D001, D002"
    assert "lat" in ds and "crs" in ds  # georeferenced in the cruise frame


#: launch points of dives surveying the same ground (each dive's lines overlap the others')
OVERLAPPING = [(11.330, 142.200), (11.333, 142.203), (11.328, 142.205)]


@pytest.mark.parametrize("spike_removal", [True, False])
def test_cruise_spike_test_equals_in_memory_across_tiles_and_dives(tmp_path, spike_removal):
    """The cruise runs the dive dtm's spike test (one noise floor over all dives, the neighbour test with halos
    across tile seams and across dives): with spikes in dives that overlap, small tiles (seams everywhere), the
    spike count, noise floor and every layer equal the in-memory grid_multibeam of the union of the soundings
    (oracle, spike test on or off as the ``grid`` settings say)."""
    from hadal.grid.cruise import cruise_dtm_dataset
    from hadal.settings.grid import GridParams

    raws = [write_cruise_dive(tmp_path / "raw" / f"d{k}", f"S{k}", la, seed=10 + k, n=6000, spikes=0.01)
            for k, la in enumerate(OVERLAPPING)]
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    from hadal.flows.cruise import _TASKS

    from hadal.grid.cruise import serial_map

    seen: set[str] = set()

    def flow_map(fn, items):
        """The cruise flow hands every unit of work to a Prefect task of its table: each phase must have one."""
        assert fn.__name__ in _TASKS, f"{fn.__name__} has no task in flows/cruise.py"
        seen.add(fn.__name__)
        return serial_map(fn, items)

    ds, _ = cruise_dtm_dataset([str(r) for r in raws], 20.0, scratch, tile_cells=8, min_task_points=4000,
                               params=GridParams(spike_removal=spike_removal), map=flow_map)
    assert {"read_dive", "partition_dive", "reduce_tiles"} <= seen
    assert spike_removal == ({"tile_cell_mads", "spike_tiles"} <= seen)
    ref, _ = oracle_dtm(raws, 20.0, OVERLAPPING, remove_spikes=spike_removal)
    assert ds.attrs["n_tiles"] > 16
    assert (ref.attrs["n_soundings_spikes"] > 300) == spike_removal  # ~1 % of 36 000, and the noisy tail
    assert_same_dtm(ds, ref)


def test_bad_dive_and_files_are_named_and_left_out(tmp_path):
    """A dive whose only file is garbage, a missing file, a directory with no dive.yaml: each refused by name, the
    DTM made of the rest (and equal to the oracle of the rest)."""
    from hadal.grid.cruise import cruise_dtm_dataset

    raws = make_cruise(tmp_path / "raw", n=3000)
    # dive 1 also lists a missing file: refused by name, its other files kept
    d1 = yaml.safe_load((raws[1] / "dive.yaml").read_text())
    d1["sources"]["multibeam"].append("multibeam/gone.xyz")
    (raws[1] / "dive.yaml").write_text(yaml.safe_dump(d1))
    bad = write_cruise_dive(tmp_path / "raw" / "bad", "DBAD", (11.33, 142.21), seed=9, n=10, lines=1)
    rel = yaml.safe_load((bad / "dive.yaml").read_text())["sources"]["multibeam"][0]
    (bad / rel).write_bytes(b"\x00\x01garbage" * 50)
    nodive = tmp_path / "raw" / "nodive"
    nodive.mkdir()
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    ds, prov = cruise_dtm_dataset([str(r) for r in raws] + [str(bad), str(nodive)], 20.0, scratch, tile_cells=16)
    assert str(nodive) in prov["refused_raw_dirs"]
    assert not prov["dives"]["DBAD"]["used"] and "DBAD" in prov["dives"]["DBAD"]["error"]
    assert any("gone.xyz" in f for f in prov["dives"]["D001"]["files_refused"])
    assert prov["dives"]["D001"]["used"] and len(prov["dives"]["D001"]["files_used"]) == 2
    assert "DBAD" in ds.attrs["cruise_dives_refused"] and ds.attrs["cruise_dives"] == "D000, D001, D002"
    ref, _ = oracle_dtm(raws, 20.0)
    assert_same_dtm(ds, ref)


def test_no_usable_dive_is_one_line_error(tmp_path):
    from hadal.errors import InputError
    from hadal.grid.cruise import cruise_dtm_dataset

    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no dive with multibeam soundings"):
        cruise_dtm_dataset([str(tmp_path / "empty")], 20.0, tmp_path)


@pytest.mark.integration
def test_cli_cruise_dtm_on_a_local_cluster(tmp_path):
    """``hadal cruise-dtm DIVES --cruise ID --resolution-m R`` (a LocalCluster of one worker, a temporary Prefect
    server): prints the published file, which equals the oracle of all the dives' soundings."""
    import os
    import subprocess
    import sys

    import xarray as xr

    raws = make_cruise(tmp_path / "raw", n=4000)
    env = {**os.environ, "PREFECT_SERVER_ANALYTICS_ENABLED": "false", "HADAL_PROGRESS": "none"}
    r = subprocess.run([sys.executable, "-m", "hadal.cli", "cruise-dtm", *map(str, raws), "--cruise", "C1",
                        "--resolution-m", "20", "--workers", "1", "--store", str(tmp_path / "store")],
                       capture_output=True, text=True, timeout=600, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    line = next(ln for ln in r.stdout.splitlines() if ln.startswith("cruise DTM: "))
    path = Path(line.removeprefix("cruise DTM: ").split(" (")[0])
    assert path.is_file() and path.parent.parent.parent.name == "C1" and "(3 dive(s))" in line
    ref, _ = oracle_dtm(raws, 20.0)
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        np.testing.assert_array_equal(ds["count"].values, ref["count"].values)
        np.testing.assert_allclose(ds["depth_m"].values, ref["depth_m"].values.astype(np.float32), rtol=0,
                                   atol=1e-3, equal_nan=True)
