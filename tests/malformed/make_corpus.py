"""Generate the malformed-input corpus for the ingest stage: one raw dive directory per defect.

Usage: ``PYTHONPATH=src python tests/malformed/make_corpus.py DEST`` writes ``DEST/<case>/`` and prints the
cases. ``tests/robustness/test_ingest_malformed.py`` runs the ingest stage on every case and asserts the outcome:
either a one-line :class:`hadal.errors.HadalError` of the expected class with nothing published, or a
published product whose data/metadata flag the defect (``check``).
"""

from __future__ import annotations

import json
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import yaml

sys.path.insert(0, str(Path(__file__).parent))
from tiny_dive import messages, write_dive, write_mcap  # noqa: E402

DURATION_S = 20.0


@dataclass
class Case:
    name: str
    description: str
    make: Callable[[Path], None]           # mutates a copy of the tiny dive
    error: str | None = None               # expected HadalError subclass name (None: must publish)
    match: str = ""                        # regex the one-line message must contain
    check: Callable[[pd.DataFrame, dict], bool] | None = None  # for published cases
    source: str = "auto"


# ---------------------------------------------------------------------------------------------- helpers
def _dive_yaml(d: Path, **changes) -> None:
    y = yaml.safe_load((d / "dive.yaml").read_text())
    for k, v in changes.items():
        if isinstance(v, dict) and isinstance(y.get(k), dict):
            y[k].update(v)
        else:
            y[k] = v
    (d / "dive.yaml").write_text(yaml.safe_dump(y, sort_keys=False))


def _csv_only(d: Path) -> None:
    _dive_yaml(d, sources={"mcap": []})


def _rewrite_mcap(d: Path, fn: Callable[[dict], dict], sort: bool = True) -> None:
    write_mcap(d / "logs" / "haidou.mcap", fn(messages(DURATION_S)), chunk_size=2048, sort=sort)


def _mcap_bytes(d: Path, fn: Callable[[bytes], bytes]) -> None:
    p = d / "logs" / "haidou.mcap"
    p.write_bytes(fn(p.read_bytes()))


def _flip_chunk(b: bytes) -> bytes:
    import io

    from mcap.reader import make_reader

    ci = make_reader(io.BytesIO(b)).get_summary().chunk_indexes[2]
    a = bytearray(b)
    a[ci.chunk_start_offset + ci.chunk_length // 2] ^= 0xA5
    return bytes(a)


#: rows of altimeter.csv set to -1 by :func:`_no_bottom` (the oracle of the csv_altitude_no_bottom case)
_NO_BOTTOM: dict[str, int] = {}


def _no_bottom(lines: list[str]) -> list[str]:
    """altimeter.csv with the altitude of every third row set to -1 (an altimeter's "no bottom")."""
    head, rows = lines[:1], lines[1:]
    col = head[0].split(",").index(next(c for c in head[0].split(",") if c.startswith("alt")))
    out = []
    for i, r in enumerate(rows):
        f = r.split(",")
        if i % 3 == 0:
            f[col] = "-1"
        out.append(",".join(f))
    _NO_BOTTOM["rows"] = len(rows[::3])
    return head + out


def _edit_csv(d: Path, name: str, fn: Callable[[list[str]], list[str]]) -> None:
    p = d / "csv" / name
    p.write_text("\n".join(fn(p.read_text().splitlines())) + "\n")


def _vehicle(d: Path, text: str | None = None, edit: Callable[[dict], None] | None = None) -> None:
    p = d / "vehicle.yaml"
    if text is not None:
        p.write_text(text)
        return
    y = yaml.safe_load(p.read_text())
    edit(y)
    p.write_text(yaml.safe_dump(y, sort_keys=False))


def _set_field(topic: str, field: str, fn: Callable[[int, object], object]) -> Callable[[dict], dict]:
    def f(msgs: dict) -> dict:
        msgs[topic] = [(t, {**m, field: fn(i, m[field])}) for i, (t, m) in enumerate(msgs[topic])]
        return msgs
    return f


def _json_garbage(d: Path) -> None:
    # rewrite the MCAP with 5 CTD payloads that are not JSON
    from mcap.writer import CompressionType, Writer
    from tiny_dive import REPO, TOPICS

    msgs = messages(DURATION_S)
    p = d / "logs" / "haidou.mcap"
    with open(p, "wb") as fh:
        w = Writer(fh, chunk_size=2048, compression=CompressionType.ZSTD)
        w.start()
        ch = {}
        for topic, (_, sf) in TOPICS.items():
            sid = w.register_schema(topic, "jsonschema", (REPO / "schemas" / "mcap" / sf).read_bytes())
            ch[topic] = w.register_channel(topic, "json", sid)
        for topic, lst in msgs.items():
            for i, (t, m) in enumerate(lst):
                data = b"{not json" if topic == "/haidou/ctd" and i % 50 == 7 else json.dumps(m).encode()
                w.add_message(ch[topic], t, data, t)
        w.finish()


# ---------------------------------------------------------------------------------------------- checks
def _flag(df: pd.DataFrame, var: str, value: int) -> bool:
    return bool((df[f"{var}_qc"] == value).any())


CASES: list[Case] = [
    Case("mcap_truncated", "MCAP cut at 60 %: intact chunks recovered, loss count unknown",
         lambda d: _mcap_bytes(d, lambda b: b[: len(b) * 6 // 10]),
         check=lambda df, m: m["messages_lost"] is None and m["mcap"][0]["truncated"] and len(df) > 50),
    Case("mcap_bitflip_chunk", "one byte flipped inside a compressed chunk: chunk skipped, loss counted",
         lambda d: _mcap_bytes(d, _flip_chunk),
         check=lambda df, m: m["mcap"][0]["corrupt_chunks"] == 1 and m["messages_lost"] > 0),
    Case("mcap_empty", "0-byte MCAP file", lambda d: _mcap_bytes(d, lambda b: b""), "InputError", "empty"),
    Case("mcap_not_mcap", "text file named .mcap", lambda d: _mcap_bytes(d, lambda b: b"timestamp,value\n1,2\n"),
         "InputError", "not an MCAP file"),
    Case("mcap_header_only", "MCAP truncated inside the first record: no messages",
         lambda d: _mcap_bytes(d, lambda b: b[:40]), "InputError", "missing required channel"),
    Case("mcap_missing_ctd_topic", "no /haidou/ctd channel",
         lambda d: _rewrite_mcap(d, lambda m: {k: v for k, v in m.items() if k != "/haidou/ctd"}),
         "InputError", "missing required channel"),
    Case("mcap_missing_optional_topic", "no altimeter channel: column empty, flag 9",
         lambda d: _rewrite_mcap(d, lambda m: {k: v for k, v in m.items() if k != "/haidou/altimeter"}),
         check=lambda df, m: bool((df["altitude_m_qc"] == 9).all()) and df["altitude_m"].isna().all()),
    # issue 43 (degrade per channel): the unit mistake kills the conductivity channel only (flag 4, the unit hint
    # in the warning and the metadata); temperature and pressure are processed (was: the whole dive refused)
    Case("mcap_wrong_units", "conductivity logged in mS/cm, declared S/m: dead channel with a unit hint",
         lambda d: _rewrite_mcap(d, _set_field("/haidou/ctd", "cond", lambda i, v: v * 10.0)),
         check=lambda df, m: bool((df["conductivity_s_m_qc"].isin([4, 9])).all())
         and "mS/cm" in m["dead_channels"]["conductivity_s_m"]["hint"]
         and "vehicle config" in m["dead_channels"]["conductivity_s_m"]["hint"]
         and bool((df["temperature_its90_degc_qc"] != 4).mean() > 0.9)
         and any("conductivity_s_m is dead" in n for n in m["notes"])),
    Case("mcap_field_renamed", "vehicle maps 'cond' but the messages carry 'conductivity'",
         lambda d: _rewrite_mcap(d, lambda m: {**m, "/haidou/ctd": [
             (t, {("conductivity" if k == "cond" else k): v for k, v in x.items()}) for t, x in m["/haidou/ctd"]]}),
         "InputError", "has no field 'cond'"),
    Case("mcap_undecodable_json", "every 50th CTD payload is not JSON: dropped and counted", _json_garbage,
         check=lambda df, m: m["mcap"][0]["decode_errors"] == 7 and m["messages_lost"] == 7),
    Case("mcap_nan_inf", "NaN and inf temperatures: flag 9",
         lambda d: _rewrite_mcap(d, _set_field("/haidou/ctd", "temp",
                                               lambda i, v: float("inf") if i == 10 else (float("nan") if i == 11 else v))),
         check=lambda df, m: df["temperature_its90_degc_qc"].iloc[10] == 9 and df["temperature_its90_degc_qc"].iloc[11] == 9
         and m["non_finite_values"].get("temperature_its90_degc") == 1),
    Case("mcap_out_of_range_spike", "one gauge pressure of 99 999 dbar: flag 4",
         lambda d: _rewrite_mcap(d, _set_field("/haidou/keller", "pressure", lambda i, v: 99_999.0 if i == 40 else v)),
         check=lambda df, m: _flag(df, "pressure_gauge_dbar", 4)),
    Case("mcap_saturated_pressure", "CTD pressure at the SBE49 limit (10 500 dbar): flag 4",
         lambda d: _rewrite_mcap(d, _set_field("/haidou/ctd", "pres", lambda i, v: min(v + 80.0, 10_500.0))),
         check=lambda df, m: bool((df.loc[df["pressure_ctd_dbar"] >= 10_500, "pressure_ctd_dbar_qc"] == 4).all())
         and _flag(df, "pressure_ctd_dbar", 4)),
    Case("mcap_duplicate_out_of_order", "CTD messages duplicated and out of order: sorted, counted",
         lambda d: _rewrite_mcap(d, lambda m: {**m, "/haidou/ctd": m["/haidou/ctd"][:100] + m["/haidou/ctd"][90:95]
                                               + m["/haidou/ctd"][100:]}, sort=False),
         check=lambda df, m: m["alignment"]["ctd"]["duplicates"] == 5 and m["alignment"]["ctd"]["out_of_order"] >= 1
         and df["time"].is_monotonic_increasing and df["time"].is_unique),
    Case("mcap_gauge_gap", "10 s hole in the gauge: NaN + flag 9, no interpolation",
         lambda d: _rewrite_mcap(d, lambda m: {**m, "/haidou/keller": m["/haidou/keller"][:20] + m["/haidou/keller"][60:]}),
         check=lambda df, m: int((df["pressure_gauge_dbar_qc"] == 9).sum()) >= 8 * 16
         and df["pressure_gauge_dbar"].iloc[16 * 8] != df["pressure_gauge_dbar"].iloc[16 * 8]),
    Case("mcap_single_ctd_sample", "only one CTD message", lambda d: _rewrite_mcap(
        d, lambda m: {**m, "/haidou/ctd": m["/haidou/ctd"][:1]}), "InputError", "only 1 sample"),
    Case("mcap_listed_but_absent", "dive.yaml lists an MCAP file that does not exist",
         lambda d: (d / "logs" / "haidou.mcap").unlink(), "InputError", "does not exist"),
    Case("csv_missing_column", "ctd.csv without the conductivity column",
         lambda d: (_csv_only(d), _edit_csv(d, "ctd.csv", lambda L: [",".join(x.split(",")[:1] + x.split(",")[2:]) for x in L])),
         "InputError", "missing column.*conductivity_mS_cm"),
    Case("csv_corrupt_rows", "garbage rows and a wrong field count in ctd.csv: dropped and counted",
         lambda d: (_csv_only(d), _edit_csv(d, "ctd.csv", lambda L: L[:50] + ["xx,yy", "2018-10-06T23:00:03Z,abc,1,2",
                                                                           "2018-10-06T23:00:03Z,1,2,3,4,5"] + L[50:])),
         check=lambda df, m: m["read_stats"]["ctd"]["corrupt_rows"] == 3 and len(df) == 320),
    Case("csv_empty", "empty keller.csv", lambda d: (_csv_only(d), (d / "csv" / "keller.csv").write_text("")),
         "InputError", "empty"),
    Case("csv_header_only", "ctd.csv with a header and no rows",
         lambda d: (_csv_only(d), _edit_csv(d, "ctd.csv", lambda L: L[:1])), "InputError", "no usable rows"),
    Case("csv_bad_times", "every time in ctd.csv unparseable",
         lambda d: (_csv_only(d), _edit_csv(d, "ctd.csv", lambda L: L[:1] + ["yesterday" + x[x.index(","):] for x in L[1:]])),
         "InputError", "no usable rows"),
    Case("csv_non_monotonic", "attitude.csv reversed in time: sorted, counted",
         lambda d: (_csv_only(d), _edit_csv(d, "attitude.csv", lambda L: L[:1] + L[1:][::-1])),
         check=lambda df, m: m["alignment"]["attitude"]["out_of_order"] > 100 and _flag(df, "heading_deg", 1)),
    Case("csv_nan_inf", "'nan' and 'inf' in dr.csv", lambda d: (_csv_only(d), _edit_csv(
        d, "dr.csv", lambda L: L[:3] + [L[3].rsplit(",", 3)[0] + ",inf,nan,0.5"] + L[4:])),
         check=lambda df, m: m["non_finite_values"].get("dr_east_m") == 1 and _flag(df, "dr_east_m", 1)),
    Case("csv_extra_column", "an unmapped extra column in ctd.csv: ignored",
         lambda d: (_csv_only(d), _edit_csv(d, "ctd.csv", lambda L: [L[0] + ",oxygen_ml_l"] + [x + ",5.1" for x in L[1:]])),
         check=lambda df, m: len(df) == 320 and "oxygen_ml_l" not in df.columns),
    Case("csv_renamed_column", "keller.csv header says pressure_dbar instead of pressure_bar",
         lambda d: (_csv_only(d), _edit_csv(d, "keller.csv", lambda L: ["time,pressure_dbar"] + L[1:])),
         "InputError", "missing column.*pressure_bar"),
    # issue 43 (degrade per channel): the gauge channel is dead with a unit hint; the CTD is processed (was: refused)
    Case("csv_mixed_units", "keller.csv logged in dbar but declared bar: dead gauge channel with a unit hint",
         lambda d: (_csv_only(d), _edit_csv(d, "keller.csv", lambda L: L[:1] + [
             f"{x.split(',')[0]},{float(x.split(',')[1]) * 10:.3f}" for x in L[1:]])),
         check=lambda df, m: bool(df["pressure_gauge_dbar_qc"].isin([4, 9]).all())
         and "logged in dbar rather than bar" in m["dead_channels"]["pressure_gauge_dbar"]["hint"]
         and bool((df["pressure_ctd_dbar_qc"] == 1).mean() > 0.5)),
    # issue 43: an altimeter writing -1 for "no bottom" (a fill value for altitude only): those rows are missing
    # (flag 9), the rest is kept and the dive is processed. Oracle: the file's own -1 count and values
    Case("csv_altitude_no_bottom", "altimeter.csv with altitude -1 ('no bottom') in every third row: missing, not fatal",
         lambda d: (_csv_only(d), _edit_csv(d, "altimeter.csv", _no_bottom)),
         check=lambda df, m: m["fill_values"]["altitude_m"]["count"] == _NO_BOTTOM["rows"]
         and m["fill_values"]["altitude_m"]["values_as_logged"] == [-1.0]
         and "altitude_m" not in m.get("dead_channels", {})
         and bool((df["altitude_m"].dropna() >= 0).all()) and bool((df["altitude_m_qc"] == 9).any())
         and bool(df["altitude_m"].notna().mean() > 0.3)
         and bool(df["temperature_its90_degc"].notna().all())),
    Case("csv_duplicated_time", "every ctd.csv row twice: duplicates dropped and counted",
         lambda d: (_csv_only(d), _edit_csv(d, "ctd.csv", lambda L: L[:1] + [x for x in L[1:] for _ in (0, 1)])),
         check=lambda df, m: m["alignment"]["ctd"]["duplicates"] == 320 and len(df) == 320 and df["time"].is_unique),
    Case("csv_gigantic_values", "1e308 temperatures in ctd.csv: flagged bad (4)",
         lambda d: (_csv_only(d), _edit_csv(d, "ctd.csv", lambda L: L[:1] + [
             (",".join(x.split(",")[:2] + ["1e308"] + x.split(",")[3:]) if i % 40 == 5 else x) for i, x in enumerate(L[1:])])),
         check=lambda df, m: int((df["temperature_its90_degc_qc"] == 4).sum()) == 8),
    Case("csv_pressure_spike", "one CTD pressure spike of +3000 dbar in ctd.csv: flagged",
         lambda d: (_csv_only(d), _edit_csv(d, "ctd.csv", lambda L: L[:1] + [
             (",".join(x.split(",")[:3] + [str(float(x.split(",")[3]) - 3000.0)]) if i == 100 else x) for i, x in enumerate(L[1:])])),
         check=lambda df, m: int(df["pressure_ctd_dbar_qc"].iloc[100]) in (3, 4)),
    Case("csv_missing_optional_file", "dive.yaml lists no altimeter CSV",
         lambda d: _dive_yaml(d, sources={"mcap": [], "csv": {k: f"csv/{f}" for k, f in
                                                              [("ctd", "ctd.csv"), ("gauge", "keller.csv"),
                                                               ("attitude", "attitude.csv"), ("dr", "dr.csv")]}}),
         check=lambda df, m: bool((df["altitude_m_qc"] == 9).all())),
    Case("vehicle_bad_yaml", "vehicle.yaml is not YAML", lambda d: _vehicle(d, "sensors: {ctd: [unclosed"),
         "ConfigError", "not valid YAML"),
    Case("vehicle_unknown_unit", "vehicle.yaml declares an unknown unit",
         lambda d: _vehicle(d, edit=lambda y: y["sensors"]["gauge"]["mcap"]["fields"]["pressure_gauge_dbar"].update(units="atm")),
         "ConfigError", "unknown unit 'atm'"),
    Case("vehicle_missing", "dive.yaml names a vehicle config that is not there",
         lambda d: (d / "vehicle.yaml").unlink(), "InputError", "vehicle config"),
    Case("vehicle_not_a_mapping", "vehicle.yaml is a list", lambda d: _vehicle(d, "- ctd\n- gauge\n"),
         "ConfigError", "expected a mapping"),
    Case("cnv_truncated_header", "a .cnv source without its '*END*' line",
         lambda d: ((d / "ctd.cnv").write_text("* Sea-Bird SBE 9 Data File:\n# nquan = 1\n# name 0 = prDM: Pressure [db]\n"),
                    _dive_yaml(d, sources={"mcap": [], "cnv": ["ctd.cnv"]})), "InputError", "no '\\*END\\*' line", source="cnv"),
    Case("cnv_binned_no_time", "a pressure-binned .cnv cast has no time channel: ingested as a profile (NaT times)",
         lambda d: ((d / "ctd.cnv").write_text(
             "* Sea-Bird SBE 9 Data File:\n# nquan = 3\n# name 0 = prDM: Pressure, Digiquartz [db]\n"
             "# name 1 = t090C: Temperature [ITS-90, deg C]\n# name 2 = c0S/m: Conductivity [S/m]\n"
             "# interval = decibars: 1\n# start_time = Oct 06 2018 23:00:00\n*END*\n"
             "      1.000    20.0000   5.000000\n      2.000    19.9000   4.990000\n"),
                    _dive_yaml(d, sources={"mcap": [], "cnv": ["ctd.cnv"]})),
         check=lambda df, m: m["time_base"] == "none (pressure-binned cast)" and bool(df["time"].isna().all())
         and len(df) == 2, source="cnv"),
    Case("dive_no_sources", "dive.yaml lists neither MCAP nor CSV",
         lambda d: _dive_yaml(d, sources={"mcap": [], "csv": {}}), "InputError", "neither MCAP, CSV nor .cnv"),
]


# ---------------------------------------------------------------------------------------------- round 2 (issue 14)
def _every(k: int, value):
    """Field setter: ``value(v)`` on every k-th message (from the 3rd), the value kept elsewhere."""
    return lambda i, v: value(v) if i % k == 3 else v


def _write_channels(d: Path, chans: list[tuple[str, str, bytes, list[tuple[int, dict]]]], rest: bool = True) -> None:
    """MCAP whose channels are given as (topic, schema name, schema data, messages); ``rest``: the other
    tiny-dive topics as usual."""
    from mcap.writer import CompressionType, Writer
    from tiny_dive import REPO, TOPICS

    msgs = messages(DURATION_S)
    p = d / "logs" / "haidou.mcap"
    with open(p, "wb") as fh:
        w = Writer(fh, chunk_size=2048, compression=CompressionType.ZSTD)
        w.start()
        todo = []
        for topic, sname, sdata, lst in chans:
            sid = w.register_schema(sname, "jsonschema", sdata)
            todo.append((w.register_channel(topic, "json", sid), lst))
        if rest:
            for topic, (_, sf) in TOPICS.items():
                if topic == "/haidou/ctd":
                    continue
                sid = w.register_schema(topic.rsplit("/", 1)[-1], "jsonschema", (REPO / "schemas" / "mcap" / sf).read_bytes())
                todo.append((w.register_channel(topic, "json", sid), msgs[topic]))
        merged = sorted(((t, cid, m) for cid, lst in todo for t, m in lst), key=lambda x: (x[0], x[1]))
        for t, cid, m in merged:
            w.add_message(cid, t, json.dumps(m).encode(), t)
        w.finish()


def _ctd_schema() -> bytes:
    from tiny_dive import REPO

    return (REPO / "schemas" / "mcap" / "haidou_ctd.json").read_bytes()


def _ctd_two_channels(d: Path) -> None:
    """The CTD split over two channels of one topic (same schema), 10 messages recorded on both."""
    ctd = messages(DURATION_S)["/haidou/ctd"]
    a = [x for i, x in enumerate(ctd) if i % 2 == 0] + [x for i, x in enumerate(ctd) if i % 2 == 1][:10]
    b = [x for i, x in enumerate(ctd) if i % 2 == 1]
    _write_channels(d, [("/haidou/ctd", "ctd", _ctd_schema(), a), ("/haidou/ctd", "ctd", _ctd_schema(), b)])


def _ctd_two_schemas(d: Path) -> None:
    ctd = messages(DURATION_S)["/haidou/ctd"]
    other = json.dumps({"title": "ctd_v2", "type": "object", "properties": {"cond": {"type": "number"}}}).encode()
    _write_channels(d, [("/haidou/ctd", "ctd", _ctd_schema(), ctd[::2]), ("/haidou/ctd", "ctd_v2", other, ctd[1::2])])


def _shift_topic(topic: str, fn) -> Callable[[dict], dict]:
    def f(msgs: dict) -> dict:
        msgs[topic] = [(fn(i, t), m) for i, (t, m) in enumerate(msgs[topic])]
        return msgs
    return f


def _shift_all(fn) -> Callable[[dict], dict]:
    def f(msgs: dict) -> dict:
        return {k: [(fn(i, t), m) for i, (t, m) in enumerate(v)] for k, v in msgs.items()}
    return f


_YEAR_NS = 365 * 86_400 * 10**9
_BAD_FLAG = -9.990e-29


def _cnv_timeS(d: Path, bad_rows=(5, 17)) -> None:
    rows = []
    for i in range(40):
        ts = _BAD_FLAG if i in bad_rows else 0.5 * i
        rows.append(f"{100.0 + i:11.3f}{2.5 - 0.001 * i:11.4f}{3.25 + 1e-4 * i:11.6f}{ts:11.3e}")
    (d / "ctd.cnv").write_text(
        "* Sea-Bird SBE 9 Data File:\n# nquan = 4\n# nvalues = 40\n# name 0 = prDM: Pressure, Digiquartz [db]\n"
        "# name 1 = t090C: Temperature [ITS-90, deg C]\n# name 2 = c0S/m: Conductivity [S/m]\n"
        "# name 3 = timeS: Time, Elapsed [seconds]\n# interval = seconds: 0.5\n"
        "# start_time = Oct 06 2018 23:00:00\n# bad_flag = -9.990e-29\n*END*\n" + "\n".join(rows) + "\n")
    _dive_yaml(d, sources={"mcap": [], "cnv": ["ctd.cnv"]})


def _csv_shift_times(name: str, seconds: float) -> Callable[[list[str]], list[str]]:
    def f(lines: list[str]) -> list[str]:
        out = lines[:1]
        for x in lines[1:]:
            t, rest = x.split(",", 1)
            ts = pd.Timestamp(t) + pd.Timedelta(seconds=seconds)
            out.append(ts.strftime("%Y-%m-%dT%H:%M:%S.%fZ") + "," + rest)
        return out
    return f


def _csv_cells(name: str, col: int, every: int, text: str) -> Callable[[list[str]], list[str]]:
    def f(lines: list[str]) -> list[str]:
        out = lines[:1]
        for i, x in enumerate(lines[1:]):
            parts = x.split(",")
            if i % every == 3:
                parts[col] = text
            out.append(",".join(parts))
        return out
    return f


def _rej(m: dict, sensor: str) -> int:
    return int((m.get("rejected_samples") or {}).get(sensor, {}).get("samples", 0))


def _ctd_rows(n_rejected: int) -> Callable[[pd.DataFrame, dict], bool]:
    """320 CTD samples less the rejected ones, the rest of the table intact."""
    return lambda df, m: len(df) == 320 - n_rejected and _rej(m, "ctd") == n_rejected


CASES += [
    # class 2: type confusion (a value that is not a number rejects its sample, counted per field)
    Case("mcap_json_bool_value", "CTD temp is JSON true in every 40th message: those samples rejected, counted",
         lambda d: _rewrite_mcap(d, _set_field("/haidou/ctd", "temp", _every(40, lambda v: True))),
         check=lambda df, m: _ctd_rows(8)(df, m)
         and m["rejected_samples"]["ctd"]["fields"] == {"temp": {"variable": "temperature_its90_degc", "count": 8}}
         and not (df["temperature_its90_degc"] == 1.0).any() and any("not a number" in w for w in m["warnings"])),
    Case("mcap_json_array_value", "CTD pres is a one-element array [x] in every 20th message: rejected, no 2-D array",
         lambda d: _rewrite_mcap(d, _set_field("/haidou/ctd", "pres", _every(20, lambda v: [v]))),
         check=_ctd_rows(16)),
    Case("mcap_json_object_value", "gauge pressure is an object in every 10th message: rejected",
         lambda d: _rewrite_mcap(d, _set_field("/haidou/keller", "pressure", _every(10, lambda v: {"value": v}))),
         check=lambda df, m: _rej(m, "gauge") == 8 and len(df) == 320
         and m["read_stats"]["gauge"]["rejected_values"]["pressure"]["types"] == {"object": 8}),
    Case("mcap_json_string_number", "CTD cond is a string \"3.25\" in every 40th message: rejected, not coerced",
         lambda d: _rewrite_mcap(d, _set_field("/haidou/ctd", "cond", _every(40, lambda v: str(v)))),
         check=_ctd_rows(8)),
    Case("mcap_json_all_bool", "every CTD temp is a boolean: nothing usable from the time base",
         lambda d: _rewrite_mcap(d, _set_field("/haidou/ctd", "temp", lambda i, v: i % 2 == 0)),
         "InputError", r"time-base sensor .ctd. \(.*320 sample\(s\) rejected for a value that is not a number"),
    Case("mcap_json_bool_time", "the altimeter's 'stamp' mapped as a unix_s time is true in some messages",
         lambda d: (_vehicle(d, edit=lambda y: y["sensors"]["altimeter"]["mcap"].update(
             time={"field": "stamp", "format": "unix_s"})),
             _rewrite_mcap(d, _set_field("/haidou/altimeter", "stamp", _every(10, lambda v: True)))),
         check=lambda df, m: m["read_stats"]["altimeter"]["bad_times"] == 4
         and m["read_stats"]["altimeter"]["bad_time_types"] == {"bool": 4}),
    Case("csv_bool_cells", "'true' in ctd.csv temperature cells: rows rejected and counted per column",
         lambda d: (_csv_only(d), _edit_csv(d, "ctd.csv", _csv_cells("ctd.csv", 2, 40, "true"))),
         check=lambda df, m: len(df) == 312 and m["rejected_samples"]["ctd"]["fields"]["temperature_ITS90"]["count"] == 8),
    Case("csv_array_cells", "'[1.5]' in keller.csv pressure cells: rows rejected",
         lambda d: (_csv_only(d), _edit_csv(d, "keller.csv", _csv_cells("keller.csv", 1, 10, '"[1.5]"'))),
         check=lambda df, m: _rej(m, "gauge") == 8),
    # class 3: two channels on one topic
    Case("mcap_duplicate_channel_same_schema", "CTD on two channels of one topic (same schema), 10 messages on both: "
         "merged, duplicates dropped and counted",
         _ctd_two_channels,
         check=lambda df, m: len(df) == 320 and m["mcap"][0]["duplicates_dropped"] == 10
         and m["mcap"][0]["messages_lost"] == 0 and m["alignment"]["ctd"]["duplicates"] == 0),
    Case("mcap_duplicate_channel_other_schema", "CTD topic on two channels with different schemas: refused",
         _ctd_two_schemas, "InputError", r"topic /haidou/ctd is recorded on 2 channels with different schemas.*ctd_v2"),
    # class 4: time sanity
    Case("mcap_log_time_ms", "log_time written in milliseconds (data dated 1970)",
         lambda d: _rewrite_mcap(d, _shift_all(lambda i, t: t // 10**6)), "InputError",
         "outside the plausible range.*log_time looks like milliseconds"),
    Case("mcap_dated_2108", "every log time 90 years late (2108)",
         lambda d: _rewrite_mcap(d, _shift_all(lambda i, t: t + 90 * _YEAR_NS)), "InputError",
         "outside the plausible range"),
    Case("mcap_some_times_2100", "5 gauge messages dated 2100: dropped, counted and flagged",
         lambda d: _rewrite_mcap(d, _shift_topic("/haidou/keller", lambda i, t: t + 82 * _YEAR_NS if i % 16 == 5 else t)),
         check=lambda df, m: m["time_checks"]["implausible"]["gauge"]["dropped"] == 5
         and any("plausible range" in n for n in m["notes"])),
    Case("mcap_year_after_launch", "the logs are dated one year after dive.yaml's launch time",
         lambda d: _rewrite_mcap(d, _shift_all(lambda i, t: t + _YEAR_NS)), "InputError", "launch window"),
    Case("mcap_gauge_one_hour_off", "the gauge's log times are 1 h late: 0 % overlap with the CTD, warned",
         lambda d: _rewrite_mcap(d, _shift_topic("/haidou/keller", lambda i, t: t + 3600 * 10**9)),
         check=lambda df, m: m["time_checks"]["overlap"]["gauge"]["overlap"] == 0.0
         and abs(m["time_checks"]["overlap"]["gauge"]["offset_s"] - 3600) < 1
         and any("overlaps the ctd time base by only 0%" in w and "+1 h 00 min" in w for w in m["warnings"])
         and bool((df["pressure_gauge_dbar_qc"] == 9).all())),
    Case("csv_gauge_one_hour_off", "keller.csv times 1 h late (time zone): 0 % overlap, warned",
         lambda d: (_csv_only(d), _edit_csv(d, "keller.csv", _csv_shift_times("keller.csv", 3600))),
         check=lambda df, m: m["time_checks"]["overlap"]["gauge"]["overlap"] == 0.0
         and any("time zone" in n for n in m["notes"])),
    Case("csv_unix_s_is_ms", "dr.csv times given as unix_s but written in milliseconds",
         lambda d: (_csv_only(d), _vehicle(d, edit=lambda y: y["sensors"]["position"]["csv"].update(
             time={"field": "time", "format": "unix_s"})),
             _edit_csv(d, "dr.csv", lambda L: L[:1] + [
                 f"{int(pd.Timestamp(x.split(',')[0]).value // 10**6)}," + x.split(",", 1)[1] for x in L[1:]])),
         "InputError", "looks like milliseconds"),
    Case("cnv_timeS_bad_flag", "two .cnv scans whose timeS is bad_flag: dropped, no row dated 1726",
         _cnv_timeS, check=lambda df, m: len(df) == 38 and df["time"].min().year == 2018
         and m["read_stats"]["ctd"]["bad_times"] == 2, source="cnv"),
    Case("cnv_all_timeS_bad_flag", "every .cnv timeS is bad_flag",
         lambda d: _cnv_timeS(d, bad_rows=range(40)), "InputError", "bad_flag or not a number", source="cnv"),
]


def build_corpus(dest: str | Path) -> list[tuple[Case, Path]]:
    """Write every case's dive directory under ``dest``; returns (case, directory) pairs."""
    dest = Path(dest)
    base = write_dive(dest / "_base", DURATION_S, dive_id="malformed")
    _rewrite_mcap(base, lambda m: m)  # smaller chunks: several per file
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
        sys.exit("usage: make_corpus.py DEST")
    for c, _d in build_corpus(sys.argv[1]):
        print(f"{c.name:32s} {'-> ' + c.error if c.error else '-> published, flagged':28s} {c.description}")
    print(f"{len(CASES)} cases")
