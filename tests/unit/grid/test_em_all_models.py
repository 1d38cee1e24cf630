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


def _repack(dgms, order_out, model=None, edit=None):
    """The EM3000 datagrams (big-endian as read) re-packed in ``order_out`` field by field with struct (header,
    Depth and Position fields; other types keep their body bytes), the model number optionally replaced, the
    checksum redone: an independent byte-order conversion written from 850-160692."""
    out = bytearray()
    for typ, _m, _date, _t, b in dgms:
        nb = bytearray(b)
        hdr = list(struct.unpack_from(">HIIHH", b, 2))
        if model is not None:
            hdr[0] = model
        struct.pack_into(order_out + "HIIHH", nb, 2, *hdr)
        if typ == 0x44:
            f = struct.unpack_from(">HHHBBBBH", b, 16)
            struct.pack_into(order_out + "HHHBBBBH", nb, 16, *f)
            for i in range(f[4]):
                v = list(struct.unpack_from(">HhhhHH", b, 28 + 16 * i))
                if edit is not None:
                    v = edit(v)
                struct.pack_into(order_out + "HhhhHH", nb, 28 + 16 * i, *v)
        elif typ == 0x50:
            f = struct.unpack_from(">iiHHHH", b, 16)
            struct.pack_into(order_out + "iiHHHH", nb, 16, *f)
        struct.pack_into(order_out + "H", nb, len(nb) - 2, sum(nb[1:-3]) & 0xFFFF)
        out += struct.pack(order_out + "I", len(nb)) + nb
    return bytes(out)


@pytest.mark.parametrize("order", ["<", ">"])
@pytest.mark.parametrize("model", [120, 122, 300, 302, 710, 1002, 2000, 2040, 3003, 3020])
def test_em_all_every_model_and_byte_order_reads_the_same_soundings(em3000, tmp_path, model, order):
    """The EM3000 file re-packed as another EM model (MB-System mbsys_simrad2.h/mbsys_simrad3.h numbers) in
    either byte order: the order is found from the model number, the soundings equal the original's."""
    from hadal.grid.sonar import read_multibeam

    _order, dgms = _walk(em3000)
    p = tmp_path / "m.all"
    p.write_bytes(_repack(dgms, order, model))
    ref, got = read_multibeam(em3000), read_multibeam(p)
    assert got.attrs["byte_order"] == ("little" if order == "<" else "big") and got.attrs["em_model"] == model
    for c in ("longitude_deg", "latitude_deg", "depth_m"):
        np.testing.assert_allclose(got[c].to_numpy(), ref[c].to_numpy(), rtol=0, atol=1e-9)


@pytest.mark.parametrize("model,unsigned", [(120, True), (300, True), (3000, False), (710, False)])
def test_em_all_depth_z_is_unsigned_for_em120_and_em300_only(em3000, tmp_path, model, unsigned):
    """850-160692 / MB-System mbr_em300raw_rd_bath: the Depth datagram's z is u16 for EM 120/300 (deep water,
    up to 655 m x z resolution), i16 for the others. z + 40000 (above 32767) is 400 m deeper when unsigned;
    signed, the same bits are a negative depth below the transducer (z - 25536 cm)."""
    from hadal.grid.sonar import read_multibeam

    _order, dgms = _walk(em3000)
    p = tmp_path / "u.all"
    p.write_bytes(_repack(dgms, ">", model, edit=lambda v: [v[0] + 40000 if v[0] else 0, *v[1:]]))
    ref = _depth_pings(">", dgms)
    zres_cm = [b[24] for typ, *_r, b in dgms if typ == 0x44]  # HHHBBBBH at 16: ..., N at 23, z resolution at 24
    shift_m = 40000 if unsigned else 40000 - 65536
    want = np.concatenate([p_[2] + 0.01 * shift_m * zr for p_, zr in zip(ref, zres_cm, strict=True)])
    got = read_multibeam(p)
    np.testing.assert_allclose(got["depth_m"].to_numpy(), want, atol=1e-4)


def test_em_all_big_endian_length_multiple_of_256_is_read_big_endian(em3000, tmp_path):
    """A big-endian first datagram of 256 bytes reads 65536 little-endian, also a plausible length: the byte order
    comes from the model number (3000 big-endian, 47115 little-endian), not from the length."""
    from hadal.grid.sonar import read_multibeam

    body = b"\x02T" + struct.pack(">HIIHH", 3000, 19990217, 55600000, 1, 207) + struct.pack(">HHhB", 1, 0, 12, 0)
    body = bytearray(body + b"\x00" * (256 - len(body) - 3) + b"\x03\x00\x00")
    struct.pack_into(">H", body, len(body) - 2, sum(body[1:-3]) & 0xFFFF)
    assert len(body) == 256 and 16 <= struct.unpack("<I", struct.pack(">I", 256))[0] <= 1 << 24
    (tmp_path / "t.all").write_bytes(struct.pack(">I", 256) + bytes(body) + em3000.read_bytes())
    got = read_multibeam(tmp_path / "t.all")
    assert got.attrs["byte_order"] == "big" and len(got) == 7537


@pytest.mark.parametrize("order", ["<", ">"])
def test_em_all_unknown_model_is_refused_in_one_line_naming_it(em3000, tmp_path, order):
    from hadal.errors import InputError
    from hadal.grid.sonar import read_multibeam

    _order, dgms = _walk(em3000)
    (tmp_path / "x.all").write_bytes(_repack(dgms, order, 4242))
    with pytest.raises(InputError, match=r"unknown EM model number .*4242") as ei:
        read_multibeam(tmp_path / "x.all")
    assert "\n" not in str(ei.value)


@pytest.mark.parametrize("order", ["<", ">"])
def test_em_all_xyz88_of_an_em2040_in_either_order(em3000, tmp_path, order):
    """Every Depth datagram rewritten as an XYZ 88 (0x58) datagram of an EM 2040 (f32 z re transducer + f32
    transducer depth, 850-160692): depths equal the Depth datagrams' z*zres + transducer depth of the walk."""
    from hadal.grid.sonar import read_multibeam

    _order, dgms = _walk(em3000)
    out = bytearray()
    for typ, _m, date, t, b in dgms:
        if typ == 0x50:
            out += _repack([(typ, _m, date, t, b)], order, 2040)
            continue
        if typ != 0x44:
            continue
        heading, ssv, tdepth, _nmax, nb, zres, xyres, _sr = struct.unpack_from(">HHHBBBBH", b, 16)
        cnt, ser = struct.unpack_from(">HH", b, 12)
        body = struct.pack(order + "HHfHHfB3x", heading, ssv, 0.01 * tdepth, nb, nb, 1000.0, 0)
        for i in range(nb):
            z, y, x = struct.unpack_from(">hhh", b, 28 + 16 * i)
            det = 0 if z != 0 else 0x80  # z = 0 (no detection) is flagged invalid in XYZ 88
            body += struct.pack(order + "fffHBbBbh", z * 0.01 * zres, y * 0.01 * xyres, x * 0.01 * xyres,
                                0, 0, 0, det, 0, 0)
        pl = b"X" + struct.pack(order + "HIIHH", 2040, date, int(round(t * 1000)), cnt, ser) + body + b"\x00"
        d = b"\x02" + pl + b"\x03" + struct.pack(order + "H", sum(pl) & 0xFFFF)
        out += struct.pack(order + "I", len(d)) + d
    (tmp_path / "x88.all").write_bytes(bytes(out))
    got = read_multibeam(tmp_path / "x88.all")
    want = np.concatenate([p[2] for p in _depth_pings(">", dgms)])
    assert got.attrs["em_model"] == 2040 and got.attrs["datagrams"]["X"] == 67
    np.testing.assert_allclose(got["depth_m"].to_numpy(), want, atol=1e-4)
