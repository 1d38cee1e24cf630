"""Kongsberg EM ``.all`` of other models and byte orders: the real big-endian EM3000 file of PDAL's MB-System test
data (dives-real/pdal_mbf_em300raw.all) against an independent datagram walk written here from Kongsberg's "EM
Series datagram formats" (850-160692) and MB-System's mbsys_simrad2.h, struct by struct (no hadal code), and
pyproj's geodesics for the beam positions.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest

EM3000 = "dives-real/pdal_mbf_em300raw.all"


def _walk(path):
    """Every datagram of a .all file: (type, model, time_s_of_day, body) with the byte order of its lengths."""
    data = path.read_bytes()
    order = ">" if struct.unpack(">I", data[:4])[0] < struct.unpack("<I", data[:4])[0] else "<"
    off, out = 0, []
    while off + 4 <= len(data):
        (n,) = struct.unpack_from(order + "I", data, off)
        body = data[off + 4: off + 4 + n]
        assert body[0] == 0x02 and body[-3] == 0x03  # STX ... ETX
        typ, model, date, ms = body[1], *struct.unpack_from(order + "HII", body, 2)
        out.append((typ, model, date, ms / 1000.0, body))
        off += 4 + n
    assert off == len(data)
    return order, out


def _depth_pings(order, dgms):
    """Depth (0x44) datagrams -> list of (t_s, heading_deg, depth_m, across_m, along_m) of the beams with z != 0."""
    pings = []
    for typ, model, _date, t, b in dgms:
        if typ != 0x44:
            continue
        heading, _ssv, tdepth, _nmax, nvalid, zres, xyres, _sr = struct.unpack_from(order + "HHHBBBBH", b, 16)
        zfmt = "H" if model in (120, 300) else "h"  # 850-160692: z unsigned for EM 120 / EM 300 only
        z, y, x = [], [], []
        for i in range(nvalid):
            zi, yi, xi = struct.unpack_from(order + zfmt + "hh", b, 28 + 16 * i)
            if zi != 0:
                z.append(zi)
                y.append(yi)
                x.append(xi)
        (mult,) = struct.unpack_from("b", b, 28 + 16 * nvalid)
        dep = np.array(z) * zres * 0.01 + tdepth * 0.01 + mult * 655.36
        pings.append((t, heading * 0.01, dep, np.array(y) * xyres * 0.01, np.array(x) * xyres * 0.01,
                      tdepth * 0.01, np.array(z) * zres * 0.01))
    return pings


def _fixes(order, dgms):
    f = [(t, *struct.unpack_from(order + "ii", b, 16)) for typ, _m, _d, t, b in dgms if typ == 0x50]
    return np.array([(t, la * 5e-8, lo * 1e-7) for t, la, lo in f])


@pytest.fixture(scope="module")
def em3000(shared_data):
    p = shared_data / EM3000
    if not p.is_file():
        pytest.skip(f"{EM3000} not present")
    return p


def test_em3000_big_endian_soundings_match_an_independent_walk(em3000):
    from pyproj import Geod

    from hadal.grid.sonar import read_multibeam

    order, dgms = _walk(em3000)
    assert order == ">" and {m for typ, m, *_ in dgms if typ == 0x44} == {3000}  # installation datagrams: 3002
    pings = _depth_pings(order, dgms)
    fixes = _fixes(order, dgms)
    assert len(pings) == 67 and len(fixes) == 23
    below_tx = np.concatenate([p[6] for p in pings])
    tx = np.array([p[5] for p in pings])
    assert len(below_tx) == 7537 and 2.41 < below_tx.min() < below_tx.max() < 3.24 and 1.58 < tx.min() <= tx.max() < 1.63
    df = read_multibeam(em3000)
    assert df.attrs["byte_order"] == "big" and df.attrs["em_model"] == 3000 and len(df) == 7537
    geod = Geod(ellps="WGS84")
    inside = 0
    for i, (t, heading, dep, across, along, _tx, _z) in enumerate(pings):
        got = df[df["ping"] == i]
        np.testing.assert_allclose(got["depth_m"].to_numpy(), dep, atol=1e-5)  # float32 storage
        if not fixes[0, 0] <= t <= fixes[-1, 0]:
            continue  # before/after the fixes: dead-reckoned, checked below by the ranges only
        inside += 1
        lat0, lon0 = np.interp(t, fixes[:, 0], fixes[:, 1]), np.interp(t, fixes[:, 0], fixes[:, 2])
        az, _baz, dist = geod.inv(np.full(len(dep), lon0), np.full(len(dep), lat0), got["longitude_deg"].to_numpy(),
                                  got["latitude_deg"].to_numpy())
        np.testing.assert_allclose(dist, np.hypot(across, along), atol=0.01)  # x forward, y starboard
        far = np.hypot(across, along) > 0.5
        want_az = (heading + np.degrees(np.arctan2(across, along))) % 360
        daz = (az[far] % 360 - want_az[far] + 180) % 360 - 180
        assert np.abs(daz).max() < 0.5
    assert inside >= 60
    assert 4.0 <= df["depth_m"].min() and df["depth_m"].max() <= 4.85
    assert df["latitude_deg"].between(27.7593, 27.7596).all() and df["longitude_deg"].between(-82.6330, -82.6326).all()


def test_em3000_little_endian_copy_reads_the_same(em3000, tmp_path):
    """The same datagrams rewritten little-endian (lengths, header and Depth/Position fields swapped here):
    the reader gives the same soundings (byte order from the file, per datagram field)."""
    from hadal.grid.sonar import read_multibeam

    order, dgms = _walk(em3000)
    out = bytearray()
    for typ, _model, _date, _t, b in dgms:
        if typ not in (0x44, 0x50):
            continue
        nb = bytearray(b)
        hdr = struct.unpack_from(">HIIHH", b, 2)
        struct.pack_into("<HIIHH", nb, 2, *hdr)
        if typ == 0x44:
            f = struct.unpack_from(">HHHBBBBH", b, 16)
            struct.pack_into("<HHHBBBBH", nb, 16, *f)
            for i in range(f[4]):
                v = struct.unpack_from(">hhhhHH", b, 28 + 16 * i)
                struct.pack_into("<hhhhHH", nb, 28 + 16 * i, *v)
        else:
            f = struct.unpack_from(">iiHHHH", b, 16)
            struct.pack_into("<iiHHHH", nb, 16, *f)
        struct.pack_into("<H", nb, len(nb) - 2, sum(nb[1:-3]) & 0xFFFF)
        out += struct.pack("<I", len(nb)) + nb
    (tmp_path / "le.all").write_bytes(bytes(out))
    a, b = read_multibeam(em3000), read_multibeam(tmp_path / "le.all")
    assert b.attrs["byte_order"] == "little" and len(a) == len(b)
    for c in ("longitude_deg", "latitude_deg", "depth_m"):
        np.testing.assert_allclose(a[c].to_numpy(), b[c].to_numpy(), rtol=0, atol=1e-9)


def _rewrite(order, dgms, edit):
    """The datagrams written back (big-endian as read) after ``edit(typ, bytearray body)``, checksums redone."""
    out = bytearray()
    for typ, _model, _date, _t, b in dgms:
        nb = bytearray(b)
        edit(typ, nb)
        struct.pack_into(order + "H", nb, len(nb) - 2, sum(nb[1:-3]) & 0xFFFF)
        out += struct.pack(order + "I", len(nb)) + nb
    return bytes(out)


@pytest.mark.parametrize("psv,shift_m", [(b"2.1.2", 655.36), (b"1.5.3", 0.0)])
def test_em3000_offset_multiplier_follows_the_processor_software(em3000, tmp_path, psv, shift_m):
    """MB-System's mbr_em300raw_rd_bath: the transducer-depth offset multiplier (x 655.36 m) counts for EM 3000
    processors from software 2.0.0 on and is ignored before (they did not write it)."""
    from hadal.grid.sonar import read_multibeam

    order, dgms = _walk(em3000)
    ref = read_multibeam(em3000)

    def edit(typ, b):
        if typ == 0x49:
            i = bytes(b).index(b"PSV=") + 4
            b[i:i + 5] = psv
        elif typ == 0x44:
            nvalid = b[23]  # HHHBBBBH at 16: heading, ssv, tdepth, max beams, N, ...
            b[28 + 16 * nvalid] = 1  # offset multiplier 1 in every Depth datagram

    (tmp_path / "m.all").write_bytes(_rewrite(order, dgms, edit))
    got = read_multibeam(tmp_path / "m.all")
    np.testing.assert_allclose(got["depth_m"].to_numpy(), ref["depth_m"].to_numpy() + shift_m, atol=1e-3)


def test_em_all_broken_depth_datagram_is_dropped_and_counted(em3000, tmp_path):
    from hadal.grid.sonar import read_multibeam

    order, dgms = _walk(em3000)
    ref = read_multibeam(em3000)
    seen = []

    def edit(typ, b):
        if typ == 0x44:
            seen.append(1)
            if len(seen) == 5:  # beam numbers of the 5th ping in reverse order: a broken record
                nvalid = b[23]  # HHHBBBBH at 16: heading, ssv, tdepth, max beams, N, ...
                nums = [b[28 + 16 * i + 15] for i in range(nvalid)]
                for i, v in enumerate(reversed(nums)):
                    b[28 + 16 * i + 15] = v

    (tmp_path / "b.all").write_bytes(_rewrite(order, dgms, edit))
    got = read_multibeam(tmp_path / "b.all")
    assert got.attrs["depth_datagrams_broken"] == 1 and got.attrs["pings"] == 66
    assert len(got) == len(ref) - int((ref["ping"] == 4).sum())


def test_em_all_starting_with_any_datagram_type_is_detected(em3000, tmp_path):
    """A file whose first datagram is a type not usually first (a Tide 'T' datagram here): recognised by its ETX and
    checksum (formats.detect), read as before."""
    from hadal.formats import detect
    from hadal.grid.sonar import read_multibeam

    order, dgms = _walk(em3000)
    tide = bytearray(b"\x02T" + struct.pack(">HIIHH", 3000, 19990217, 55600000, 1, 207) + struct.pack(">HHhB", 1, 0, 12, 0)
                     + b"\x03\x00\x00")
    struct.pack_into(">H", tide, len(tide) - 2, sum(tide[1:-3]) & 0xFFFF)
    (tmp_path / "t.bin").write_bytes(struct.pack(">I", len(tide)) + bytes(tide) + em3000.read_bytes())
    assert detect(tmp_path / "t.bin").kind == "em_all"
    assert len(read_multibeam(tmp_path / "t.bin")) == 7537
