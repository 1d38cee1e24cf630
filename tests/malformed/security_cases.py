"""Security cases of the reliability report (issue 45): a forged provenance, a hand-edited store, hostile names and
YAML, a symlinked file offered to the report, AlignCTD's edge, grid files reaching outside the dive or to the network
(a VRT, HDF5 external storage) and compression bombs against the decode budget (a file of many small MCAP chunks
among them).

Each case is ``(name, prepare(case_dir, store), run(case_dir, store), error, match, check)`` in the shape of
``tests/reliability_report.py``'s ``Item``: a one-line :class:`hadal.errors.HadalError` of class ``error`` whose
message matches ``match`` with the store unchanged, or (``error`` None) a result that ``check`` verifies against an
independent oracle (:mod:`hashlib` of the file, the bytes the case planted).
"""

from __future__ import annotations

import base64
import contextlib
import hashlib
import json
import os
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tiny_dive import write_dive

DIVE = "sec-dive"
SECRET = b"\x89PNG\r\n\x1a\n" + b"SECRET-OUTSIDE-THE-STORE" * 40


@dataclass
class SecurityCase:
    name: str
    prepare: Callable[[Path, Path], None]
    run: Callable[[Path, Path], Any]
    error: str | None
    match: str
    check: Callable[[Path, Any], bool] | None = None


# ------------------------------------------------------------------------------------ helpers
def _publish(store: Path, product: str = "sensors", files: dict[str, bytes] | None = None, **kw: Any):
    from hadal.store import ProductStore

    with ProductStore(store).publish(DIVE, product, **kw) as draft:
        for name, data in (files or {"sensors.parquet": b"0123456789" * 100}).items():
            p = draft.path / name
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes(data)
    return draft.result


def _read_upstream(store: Path, product: str = "sensors") -> Any:
    """What a stage does to read an upstream product (``StageContext.upstream``)."""
    from hadal.stages import StageContext
    from hadal.store import ProductStore

    ctx = StageContext(dive=None, raw_dir=store, store=ProductStore(store), config=None)  # type: ignore[arg-type]
    ctx.pins[product] = ProductStore(store).latest(DIVE, product)
    return ctx.upstream(product)


@contextlib.contextmanager
def _new_process_memory():
    """As in a new process: no file hashed yet (``hadal.store._PROCESS_HASHES`` empty, restored after)."""
    import hadal.store as hs

    saved = hs._PROCESS_HASHES
    hs._PROCESS_HASHES = {}
    try:
        yield
    finally:
        hs._PROCESS_HASHES = saved


def _raw_input(d: Path) -> Path:
    f = d / "raw.bin"
    if not f.exists():
        d.mkdir(parents=True, exist_ok=True)
        f.write_bytes(hashlib.sha256(b"seed").digest() * 4096)
    return f


def _edit_manifest(store: Path, edit: Callable[[dict], None]) -> None:
    pv = _publish(store)
    m = json.loads(pv.manifest_path.read_text())
    edit(m)
    pv.manifest_path.write_text(json.dumps(m))


# ------------------------------------------------------------------------------------ cases
def _prep_poisoned(d: Path, store: Path) -> None:
    from hadal.store import HASH_CACHE

    raw = _raw_input(d)
    _publish(store, inputs=[raw])
    cache = store / HASH_CACHE
    data = json.loads(cache.read_text())
    data[str(raw.resolve())]["sha256"] = "0" * 64  # same identity (device, inode, size, mtime, ctime), wrong hash
    cache.write_text(json.dumps(data))


def _run_poisoned(d: Path, store: Path) -> Any:
    with _new_process_memory():
        return _publish(store, inputs=[_raw_input(d)])


def _check_poisoned(d: Path, pv: Any) -> bool:
    return pv.manifest()["inputs"][0]["sha256"] == hashlib.sha256(_raw_input(d).read_bytes()).hexdigest()


def _prep_symlinked_file(d: Path, store: Path) -> None:
    pv = _publish(store)
    (d / "outside.bin").write_bytes((pv.path / "sensors.parquet").read_bytes())  # same bytes: only the link differs
    (pv.path / "sensors.parquet").unlink()
    (pv.path / "sensors.parquet").symlink_to(d / "outside.bin")


def _prep_in_place_edit(d: Path, store: Path) -> None:
    pv = _publish(store)
    f = pv.path / "sensors.parquet"
    st = f.stat()
    with open(f, "r+b") as fh:
        fh.seek(10)
        fh.write(b"X")
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns))  # size and mtime as published


def _prep_symlinked_product_dir(d: Path, store: Path) -> None:
    _publish(store, product="ctd")
    (d / "elsewhere").mkdir(exist_ok=True)
    (store / DIVE / "sensors").symlink_to(d / "elsewhere")


def _prep_dive_yaml(text: str) -> Callable[[Path, Path], None]:
    def prep(d: Path, store: Path) -> None:
        write_dive(d, 5.0, csv=False, dive_id="sec-yaml")
        (d / "dive.yaml").write_text((d / "dive.yaml").read_text() + text)
    return prep


def _run_make_context(d: Path, store: Path) -> Any:
    from hadal.pipeline import make_context

    return make_context(d, store)


def _prep_catalog_id(d: Path, store: Path) -> None:
    write_dive(d, 5.0, csv=False, dive_id="catalog.json")


def _prep_twin(d: Path, store: Path) -> None:
    from hadal.store import ProductStore

    write_dive(d / "mine", 10.0, csv=False, dive_id="twin")
    (d / "first").mkdir(exist_ok=True)
    ProductStore(store).claim_dive("twin", d / "first", "fingerprint-of-the-first-directory")


def _run_twin(d: Path, store: Path) -> Any:
    from hadal.pipeline import make_context, run_stage

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return run_stage("ingest", make_context(d / "mine", store))


def _prep_report_link(d: Path, store: Path) -> None:
    from factories import publish_fake_products

    from hadal.store import ProductStore

    pvs = publish_fake_products(ProductStore(store), DIVE, products=("ctd", "landing"))
    (d / "secret.png").parent.mkdir(parents=True, exist_ok=True)
    (d / "secret.png").write_bytes(SECRET)
    figs = pvs["landing"].path / "figures"
    figs.mkdir(exist_ok=True)
    (figs / "zz_injected.png").symlink_to(d / "secret.png")


def _run_report(d: Path, store: Path) -> Any:
    from hadal.report import FigureOptions, build_report
    from hadal.store import ProductStore

    return build_report(ProductStore(store), DIVE, options=FigureOptions(dpi=50, width_in=4, max_points=500,
                                                                          workers=1))


def _check_report(d: Path, rep: Any) -> bool:
    return (base64.b64encode(SECRET).decode()[:60] not in rep.html
            and any("symbolic link" in n for n in rep.summary["notes"]))


def _run_align(d: Path, store: Path) -> Any:
    import numpy as np

    from hadal.ctd.align import align_ctd

    return align_ctd(np.arange(5.0), 6.0, 1.0)


# ------------------------------------------------------------------- confinement and memory (issue 45, round 3)
def _dive_dir(d: Path) -> Path:
    dive = d / "dive"
    dive.mkdir(parents=True, exist_ok=True)
    (dive / "dive.yaml").write_text("dive_id: sec-conf\n")
    return dive


def _vrt_text(source: str, relative: bool = False) -> str:
    return ('<VRTDataset rasterXSize="8" rasterYSize="8"><SRS>EPSG:32654</SRS>'
            '<GeoTransform>500000, 10, 0, 4000000, 0, -10</GeoTransform>'
            '<VRTRasterBand dataType="Float32" band="1"><SimpleSource>'
            f'<SourceFilename relativeToVRT="{int(relative)}">{source}</SourceFilename><SourceBand>1</SourceBand>'
            '</SimpleSource></VRTRasterBand></VRTDataset>')


def _prep_vrt_outside(d: Path, store: Path) -> None:
    import numpy as np
    import rasterio
    from rasterio.transform import from_origin

    with rasterio.open(d / "outside.tif", "w", driver="GTiff", width=8, height=8, count=1, dtype="float32",
                       crs="EPSG:32654", transform=from_origin(500000, 4000000, 10, 10)) as dst:
        dst.write(np.full((8, 8), -4000, np.float32), 1)
    (_dive_dir(d) / "prior.vrt").write_text(_vrt_text("../outside.tif", relative=True))


def _run_read_grid(name: str) -> Callable[[Path, Path], Any]:
    def run(d: Path, store: Path) -> Any:
        from hadal.grid.readers import read_grid

        return read_grid(d / "dive" / name)
    return run


def _run_vrt_network(d: Path, store: Path) -> Any:
    """A VRT whose source is a /vsicurl/ URL of a loopback server; the server must get no request (else the case
    ends in an AssertionError: a security finding, whatever hadal said)."""
    import http.server
    import threading

    from hadal.grid.readers import read_grid

    hits: list[str] = []

    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802
            hits.append(self.path)
            self.send_response(404)
            self.end_headers()

        do_HEAD = do_GET  # noqa: N815

        def log_message(self, *a: Any) -> None:
            pass

    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    try:
        (_dive_dir(d) / "net.vrt").write_text(_vrt_text(f"/vsicurl/http://127.0.0.1:{srv.server_address[1]}/a.tif"))
        try:
            return read_grid(d / "dive" / "net.vrt")
        finally:
            if hits:
                raise AssertionError(f"the VRT made HTTP requests {hits}")
    finally:
        srv.shutdown()
        srv.server_close()


def _prep_hdf5_external(d: Path, store: Path) -> None:
    import h5py
    import numpy as np

    z = np.full((8, 8), -4000.0)
    (d / "secret.raw").write_bytes(z.tobytes())
    with h5py.File(_dive_dir(d) / "prior.nc", "w") as h:
        h["x"] = np.arange(8.0)
        h["y"] = np.arange(8.0)
        h["x"].make_scale("x")
        h["y"].make_scale("y")
        ds = h.create_dataset("z", shape=z.shape, dtype="f8", external=[(str(d / "secret.raw"), 0, z.nbytes)])
        ds.dims[0].attach_scale(h["y"])
        ds.dims[1].attach_scale(h["x"])


def _prep_hex_bomb(d: Path, store: Path) -> None:
    import gzip

    d.mkdir(parents=True, exist_ok=True)
    with gzip.open(d / "bomb.hex", "wb", compresslevel=1) as f:
        f.write(b"* Sea-Bird SBE 9 Data File:\n*END*\n")
        block = b"0123456789ABCDEF0123\n" * 800_000
        for _ in range(200):  # 3.3 GB of scan lines
            f.write(block)


def _prep_nul_gzip(d: Path, store: Path) -> None:
    import gzip

    d.mkdir(parents=True, exist_ok=True)
    with gzip.open(d / "nul.cnv", "wb", compresslevel=1) as f:
        for _ in range(64):
            f.write(b"\x00" * (16 << 20))


def _prep_cnv_xz(d: Path, store: Path) -> None:
    import lzma

    d.mkdir(parents=True, exist_ok=True)
    head = ("* Sea-Bird SBE 9 Data File:\n# nquan = 2\n# nvalues = 10\n# name 0 = prDM: Pressure [db]\n"
            "# name 1 = timeS: Time, Elapsed [seconds]\n# bad_flag = -9.990e-29\n*END*\n")
    with lzma.open(d / "rows.cnv", "wb", preset=1) as f:
        f.write(head.encode())
        block = b"  1.000  0.000\n" * 1_000_000
        for _ in range(8):  # 8e6 scans: 128 MB of float64 scans, 4x that with the working copies
            f.write(block)


def _prep_mcap_chunks(d: Path, store: Path) -> None:
    """An MCAP file (spec: magic, Header, JSON Schema and Channel ``/ctd``, Chunks, Footer, magic) of 2,000 zstd
    chunks of 10,000 messages each (one chunk written 2,000 times: 4 MB on disk), each chunk within the budget,
    2e7 messages in all (about 5 GB as decoded objects)."""
    import struct
    import zlib

    import zstandard

    def string(b: bytes) -> bytes:
        return struct.pack("<I", len(b)) + b

    def record(op: int, body: bytes) -> bytes:
        return struct.pack("<BQ", op, len(body)) + body

    d.mkdir(parents=True, exist_ok=True)
    msgs = b"".join(record(0x05, struct.pack("<HIQQ", 1, i, i * 1_000_000, i * 1_000_000)
                           + b'{"p": 1.5, "t": 10.25, "c": 3.5}') for i in range(10_000))
    data = zstandard.ZstdCompressor(level=3).compress(msgs)
    chunk = record(0x06, struct.pack("<QQQI", 0, 10_000 * 1_000_000, len(msgs), zlib.crc32(msgs)) + string(b"zstd")
                   + struct.pack("<Q", len(data)) + data)
    magic = b"\x89MCAP0\r\n"
    with open(d / "chunks.mcap", "wb") as f:
        f.write(magic + record(0x01, string(b"") + string(b"bomb"))
                + record(0x03, struct.pack("<H", 1) + string(b"ctd") + string(b"jsonschema") + string(b"{}"))
                + record(0x04, struct.pack("<HH", 1, 1) + string(b"/ctd") + string(b"json") + struct.pack("<I", 0)))
        for _ in range(2000):
            f.write(chunk)
        f.write(record(0x02, struct.pack("<QQI", 0, 0, 0)) + magic)


def _run_file(fn: str, name: str, **kw: Any) -> Callable[[Path, Path], Any]:
    def run(d: Path, store: Path) -> Any:
        import importlib

        mod, func = fn.rsplit(".", 1)
        return getattr(importlib.import_module(mod), func)(d / name, **kw)
    return run


_LAUGHS = "lol: &a [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{c}: &{c} [{', '.join(['*' + p] * 10)}]\n" for p, c in zip("abcdefgh", "bcdefghi", strict=True))

CASES: tuple[SecurityCase, ...] = (
    SecurityCase("sec_poisoned_hash_cache", _prep_poisoned, _run_poisoned, None, "", _check_poisoned),
    SecurityCase("sec_manifest_traversal",
                 lambda d, s: _edit_manifest(s, lambda m: m["files"].append(
                     {"name": "../../../../etc/passwd", "bytes": 1, "sha256": "0" * 64})),
                 lambda d, s: _read_upstream(s), "StoreError", r"outside the version"),
    SecurityCase("sec_manifest_absolute_path",
                 lambda d, s: _edit_manifest(s, lambda m: m["files"].__setitem__(0, {**m["files"][0],
                                                                                     "name": "/etc/hostname"})),
                 lambda d, s: _read_upstream(s), "StoreError", r"outside the version"),
    SecurityCase("sec_manifest_json_bomb",
                 lambda d, s: _publish(s).manifest_path.write_text("[" * 200_000 + "]" * 200_000),
                 lambda d, s: _read_upstream(s), "StoreError", r"unreadable manifest"),
    SecurityCase("sec_symlinked_product_file", _prep_symlinked_file, lambda d, s: _read_upstream(s),
                 "StoreError", r"symbolic link"),
    SecurityCase("sec_in_place_edit_size_mtime_kept", _prep_in_place_edit, lambda d, s: _read_upstream(s),
                 "StoreError", r"modified after it was published"),
    SecurityCase("sec_symlinked_product_dir", _prep_symlinked_product_dir, lambda d, s: _publish(s),
                 "StoreError", r"symbolic link"),
    SecurityCase("sec_dive_id_catalog_json", _prep_catalog_id, _run_make_context, "ConfigError", r"reserved"),
    SecurityCase("sec_second_raw_dir_same_dive_id", _prep_twin, _run_twin, "StoreError",
                 r"belongs to raw directory"),
    SecurityCase("sec_yaml_billion_laughs", _prep_dive_yaml("notes_extra:\n  " + _LAUGHS.replace("\n", "\n  ")),
                 _run_make_context, "ConfigError", r"alias"),
    SecurityCase("sec_yaml_huge_scalar", _prep_dive_yaml("notes: " + "a" * 3_000_000 + "\n"), _run_make_context,
                 "ConfigError", r"characters"),
    SecurityCase("sec_yaml_deep_nesting", _prep_dive_yaml("notes: " + "[" * 3000 + "]" * 3000 + "\n"),
                 _run_make_context, "ConfigError", r"nested"),
    SecurityCase("sec_yaml_huge_integer", _prep_dive_yaml("extra: " + "7" * 50_000 + "\n"), _run_make_context,
                 "ConfigError", r"digits|integer"),
    SecurityCase("sec_report_symlinked_figure", _prep_report_link, _run_report, None, "", _check_report),
    SecurityCase("sec_vrt_source_outside_the_dive", _prep_vrt_outside, _run_read_grid("prior.vrt"), "ConfinementError",
                 r"outside the dive directory"),
    SecurityCase("sec_vrt_vsicurl_source_makes_no_request", lambda d, s: None, _run_vrt_network, "ConfinementError",
                 r"URL, virtual file system"),
    SecurityCase("sec_hdf5_external_storage_outside_the_dive", _prep_hdf5_external, _run_read_grid("prior.nc"),
                 "ConfinementError", r"external file"),
    SecurityCase("sec_gzip_hex_bomb", _prep_hex_bomb, _run_file("hadal.ingest.seabird_hex.read_hex", "bomb.hex"),
                 "InputError", r"decoding this Sea-Bird \.hex file needs more than"),
    SecurityCase("sec_gzip_nul_bytes_as_cnv", _prep_nul_gzip, _run_file("hadal.ingest.cnv.read_cnv", "nul.cnv"),
                 "InputError", r"bytes long: not a \.cnv"),
    SecurityCase("sec_xz_cnv_rows_past_the_budget", _prep_cnv_xz,
                 _run_file("hadal.ingest.cnv.read_cnv", "rows.cnv", max_bytes=256 << 20), "InputError",
                 r"decoding this CNV file needs more than"),
    SecurityCase("sec_mcap_many_small_chunks_past_the_budget", _prep_mcap_chunks,
                 _run_file("hadal.ingest.mcap_reader.read_mcap", "chunks.mcap"), "InputError",
                 r"chunks\.mcap: decoding this MCAP file needs more than .*limit"),
    SecurityCase("sec_align_ctd_advance_longer_than_record", lambda d, s: None, _run_align, "InputError",
                 r"not shorter than the record"),
)
