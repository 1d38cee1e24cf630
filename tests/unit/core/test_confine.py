"""Confinement of the grid readers (issue 45): a GDAL VRT naming a raster outside the dive or a network source, and
an HDF5/netCDF-4 variable stored in an external file, are refused before anything is read; no HTTP request leaves
the process (a loopback server records every request it gets: the oracle)."""

from __future__ import annotations

import http.server
import threading
from pathlib import Path

import numpy as np
import pytest

from hadal.errors import InputError


@pytest.fixture
def http_server():
    """A loopback HTTP server recording every request (the SSRF oracle)."""
    hits: list[str] = []

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802
            hits.append("GET " + self.path)
            self.send_response(404)
            self.end_headers()

        do_HEAD = do_GET  # noqa: N815

        def log_message(self, *a):
            pass

    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    t = threading.Thread(target=srv.serve_forever, daemon=True)
    t.start()
    yield srv.server_address[1], hits
    srv.shutdown()
    srv.server_close()


def _tif(path: Path, z: np.ndarray) -> Path:
    import rasterio
    from rasterio.transform import from_origin

    with rasterio.open(path, "w", driver="GTiff", width=z.shape[1], height=z.shape[0], count=1, dtype="float32",
                       crs="EPSG:32654", transform=from_origin(500000, 4000000, 10, 10)) as dst:
        dst.write(z.astype("float32"), 1)
    return path


def _vrt(path: Path, source: str, relative: bool = False, n: int = 8) -> Path:
    path.write_text(
        f'<VRTDataset rasterXSize="{n}" rasterYSize="{n}"><SRS>EPSG:32654</SRS>'
        '<GeoTransform>500000, 10, 0, 4000000, 0, -10</GeoTransform>'
        '<VRTRasterBand dataType="Float32" band="1"><SimpleSource>'
        f'<SourceFilename relativeToVRT="{int(relative)}">{source}</SourceFilename><SourceBand>1</SourceBand>'
        '</SimpleSource></VRTRasterBand></VRTDataset>')
    return path


def _dive(tmp_path: Path) -> Path:
    d = tmp_path / "dive"
    d.mkdir()
    (d / "dive.yaml").write_text("dive_id: conf\n")
    return d


def test_vrt_source_outside_the_dive_is_refused(tmp_path):
    from hadal.grid.readers import read_grid

    d = _dive(tmp_path)
    outside = _tif(tmp_path / "outside.tif", -4000 - np.arange(64.0).reshape(8, 8))
    for vrt in (_vrt(d / "abs.vrt", str(outside)), _vrt(d / "rel.vrt", "../outside.tif", relative=True)):
        with pytest.raises(InputError, match="outside the dive directory") as ei:
            read_grid(vrt)
        assert "\n" not in str(ei.value)
    link = d / "tiles"
    link.symlink_to(tmp_path)  # a symlinked directory inside the dive pointing out of it
    with pytest.raises(InputError, match="outside the dive directory"):
        read_grid(_vrt(d / "link.vrt", "tiles/outside.tif", relative=True))


def test_vrt_source_inside_the_dive_is_read_and_listed(tmp_path):
    """Allowed inside the dive: the values are the source's (rasterio on the .tif: the oracle), and
    :func:`hadal.confine.files_read` (what the manifest lists) names the VRT and its source."""
    import rasterio

    from hadal.confine import files_read
    from hadal.grid.readers import read_grid

    d = _dive(tmp_path)
    (d / "tiles").mkdir()
    z = -4000 - np.arange(64.0).reshape(8, 8)
    src = _tif(d / "tiles" / "t.tif", z)
    vrt = _vrt(d / "grid.vrt", "tiles/t.tif", relative=True)
    da = read_grid(vrt)
    with rasterio.open(src) as s:
        want = s.read(1).astype(float)[::-1]  # north-up file, ascending y in hadal
    np.testing.assert_array_equal(da.values, want)
    assert files_read(vrt) == [vrt.resolve(), src.resolve()]


@pytest.mark.parametrize("scheme", ["vsicurl", "http", "vsis3", "vsicurl_streaming", "vrt_conn"])
def test_vrt_with_a_network_source_makes_no_request(tmp_path, http_server, monkeypatch, scheme):
    from hadal.grid.readers import read_grid

    port, hits = http_server
    monkeypatch.setenv("AWS_S3_ENDPOINT", f"127.0.0.1:{port}")  # a host with S3 configured: /vsis3/ would go here
    monkeypatch.setenv("AWS_HTTPS", "NO")
    monkeypatch.setenv("AWS_NO_SIGN_REQUEST", "YES")
    monkeypatch.setenv("AWS_VIRTUAL_HOSTING", "FALSE")
    source = {"vsicurl": f"/vsicurl/http://127.0.0.1:{port}/a.tif", "http": f"http://127.0.0.1:{port}/a.tif",
              "vsis3": "/vsis3/bucket/a.tif", "vsicurl_streaming": f"/vsicurl_streaming/http://127.0.0.1:{port}/a",
              "vrt_conn": f"vrt:///vsicurl/http://127.0.0.1:{port}/a.tif"}[scheme]
    d = _dive(tmp_path)
    with pytest.raises(InputError, match="URL, virtual file system|network") as ei:
        read_grid(_vrt(d / "net.vrt", source))
    assert "\n" not in str(ei.value)
    assert hits == []


@pytest.mark.parametrize("scheme", ["vsicurl", "http", "vsis3"])
def test_gdal_env_alone_keeps_gdal_off_the_network(tmp_path, http_server, monkeypatch, scheme):
    """The second line: the GDAL options of :func:`hadal.confine.gdal_env` stop the request even when a VRT gets
    past the XML check (opened directly, as rasterio would)."""
    import rasterio

    from hadal.confine import gdal_env

    port, hits = http_server
    monkeypatch.setenv("AWS_S3_ENDPOINT", f"127.0.0.1:{port}")
    monkeypatch.setenv("AWS_HTTPS", "NO")
    monkeypatch.setenv("AWS_NO_SIGN_REQUEST", "YES")
    monkeypatch.setenv("AWS_VIRTUAL_HOSTING", "FALSE")
    source = {"vsicurl": f"/vsicurl/http://127.0.0.1:{port}/a.tif", "http": f"http://127.0.0.1:{port}/a.tif",
              "vsis3": "/vsis3/bucket/a.tif"}[scheme]
    vrt = _vrt(tmp_path / "net.vrt", source)
    with gdal_env(), pytest.raises(Exception):  # noqa: B017 - GDAL's own error; the oracle is the server
        with rasterio.open(vrt) as s:
            s.read(1)
    assert hits == []


def test_vrt_with_dtd_entities_is_refused(tmp_path):
    from hadal.grid.readers import read_grid

    d = _dive(tmp_path)
    (d / "e.vrt").write_text('<?xml version="1.0"?><!DOCTYPE x [<!ENTITY a "aaaa">]>'
                             '<VRTDataset rasterXSize="2" rasterYSize="2">&a;</VRTDataset>')
    with pytest.raises(InputError, match="DTD"):
        read_grid(d / "e.vrt")


def _h5_grid(path: Path, external: Path | None = None, virtual: Path | None = None) -> None:
    import h5py

    z = (-4000 - np.arange(64.0).reshape(8, 8)).astype("f8")
    with h5py.File(path, "w") as h:
        h["x"] = np.arange(8.0) * 10
        h["y"] = np.arange(8.0) * 10
        h["x"].make_scale("x")
        h["y"].make_scale("y")
        if external is not None:
            external.write_bytes(z.tobytes())
            ds = h.create_dataset("z", shape=z.shape, dtype="f8", external=[(str(external), 0, z.nbytes)])
        elif virtual is not None:
            with h5py.File(virtual, "w") as v:
                v["z"] = z
            layout = h5py.VirtualLayout(shape=z.shape, dtype="f8")
            layout[:] = h5py.VirtualSource(str(virtual), "z", shape=z.shape)
            ds = h.create_virtual_dataset("z", layout)
        else:
            ds = h.create_dataset("z", data=z)
        ds.dims[0].attach_scale(h["y"])
        ds.dims[1].attach_scale(h["x"])


@pytest.mark.parametrize("how", ["external", "virtual"])
def test_hdf5_variable_stored_outside_the_file_is_refused(tmp_path, how, monkeypatch):
    """The file's values live in a raw file outside the dive; refused before reading (an audit hook records every
    file the process opens: the raw file is never opened)."""
    import sys

    from hadal.grid.readers import read_grid

    d = _dive(tmp_path)
    secret = tmp_path / ("secret.raw" if how == "external" else "secret.h5")
    _h5_grid(d / "grid.nc", **{how: secret})
    opened: list[str] = []
    monkeypatch.chdir(tmp_path)

    def hook(event, args):
        if event == "open" and args and str(args[0]).endswith(secret.name):
            opened.append(str(args[0]))
    sys.addaudithook(hook)
    with pytest.raises(InputError, match="external|virtual") as ei:
        read_grid(d / "grid.nc")
    assert "\n" not in str(ei.value) and str(d / "grid.nc") in str(ei.value)
    assert opened == []


def test_self_contained_hdf5_grid_still_reads(tmp_path):
    from hadal.confine import check_hdf5_self_contained

    d = _dive(tmp_path)
    _h5_grid(d / "grid.nc")
    check_hdf5_self_contained(d / "grid.nc")  # no error


def test_vrt_prior_grid_dtm_manifest_lists_the_source(tmp_path):
    """Through the grid stage: a VRT prior grid whose source is inside the dive makes the DTM, and the dtm
    manifest's inputs name the VRT *and* the raster it reads (hashlib of each file: the oracle)."""
    import hashlib

    import yaml
    from test_prior_laser_inputs import _write_utm_tiff

    from hadal.pipeline import make_context, run_stage

    raw = tmp_path / "raw"
    (raw / "tiles").mkdir(parents=True)
    _write_utm_tiff(raw / "tiles" / "t.tif", depths=True)
    import rasterio

    with rasterio.open(raw / "tiles" / "t.tif") as s:
        n_x, n_y, t = s.width, s.height, s.transform
    (raw / "prior.vrt").write_text(
        f'<VRTDataset rasterXSize="{n_x}" rasterYSize="{n_y}"><SRS>EPSG:32654</SRS>'
        f'<GeoTransform>{t.c}, {t.a}, 0, {t.f}, 0, {t.e}</GeoTransform>'
        '<VRTRasterBand dataType="Float32" band="1"><NoDataValue>-9999</NoDataValue><SimpleSource>'
        '<SourceFilename relativeToVRT="1">tiles/t.tif</SourceFilename><SourceBand>1</SourceBand>'
        '</SimpleSource></VRTRasterBand></VRTDataset>')
    (raw / "dive.yaml").write_text(yaml.safe_dump({"dive_id": "V001", "platform": "test",
                                                   "sources": {"prior_grid": ["prior.vrt"]},
                                                   "launch": {"latitude_deg": 32.5, "longitude_deg": 141.0}}))
    pv = run_stage("grid", make_context(raw, tmp_path / "store"))["dtm"]
    inputs = {Path(i["path"]).name: i["sha256"] for i in pv.manifest()["inputs"]}
    for f in (raw / "prior.vrt", raw / "tiles" / "t.tif"):
        assert inputs[f.name] == hashlib.sha256(f.read_bytes()).hexdigest()
