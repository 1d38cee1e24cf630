"""Generate the malformed-input corpus for the ingest stage: one raw dive directory per defect.

Usage: ``PYTHONPATH=src python tests/malformed/make_corpus.py DEST`` writes ``DEST/<case>/`` and prints the
cases. ``tests/test_ingest_malformed.py`` runs the ingest stage on every case and asserts the outcome:
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
    Case("mcap_wrong_units", "conductivity logged in mS/cm, declared S/m: out-of-range detection",
         lambda d: _rewrite_mcap(d, _set_field("/haidou/ctd", "cond", lambda i, v: v * 10.0)),
         "InputError", "outside the plausible range.*wrong units"),
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
    Case("csv_mixed_units", "keller.csv logged in dbar but declared bar: out-of-range detection",
         lambda d: (_csv_only(d), _edit_csv(d, "keller.csv", lambda L: L[:1] + [
             f"{x.split(',')[0]},{float(x.split(',')[1]) * 10:.3f}" for x in L[1:]])),
         "InputError", "outside the plausible range"),
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
    Case("cnv_binned_no_time", "a pressure-binned .cnv cast has no time channel",
         lambda d: ((d / "ctd.cnv").write_text(
             "* Sea-Bird SBE 9 Data File:\n# nquan = 3\n# name 0 = prDM: Pressure, Digiquartz [db]\n"
             "# name 1 = t090C: Temperature [ITS-90, deg C]\n# name 2 = c0S/m: Conductivity [S/m]\n"
             "# interval = decibars: 1\n# start_time = Oct 06 2018 23:00:00\n*END*\n"
             "      1.000    20.0000   5.000000\n      2.000    19.9000   4.990000\n"),
                    _dive_yaml(d, sources={"mcap": [], "cnv": ["ctd.cnv"]})), "InputError", "no time channel", source="cnv"),
    Case("dive_no_sources", "dive.yaml lists neither MCAP nor CSV",
         lambda d: _dive_yaml(d, sources={"mcap": [], "csv": {}}), "InputError", "neither MCAP, CSV nor .cnv"),
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
