"""The Python API against the CLI on the same inputs: decode() equals `shimmy decode --format
csv` on the real RAV4 drive (candump, ASC, BLF) and on cantools' vectors; estimate() equals
`shimmy estimate --json`; export() writes what `shimmy export` writes; events() is the lake's
events table; bad input raises ShimmyError."""

import csv
import glob
import io
import json
import math
import os
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import shimmy_monitor as sm
from conftest import REPO, cli_estimate, run_cli

RAV4 = "logs/comma2k19-rav4/rav4_2017_seg40_bus0"
TOYOTA_DBC = "dbc/opendbc/toyota_new_mc_pt_generated.dbc"


def fmt_t(ns: int) -> str:
    """The CLI's timestamp text (src/cli/decode.rs write_time)."""
    sign = "-" if ns < 0 else ""
    s, r = divmod(abs(ns), 1_000_000_000)
    return f"{sign}{s}.{r // 1000:06d}" if r % 1000 == 0 else f"{sign}{s}.{r:09d}"


def cli_rows(shimmy_bin, dbc, logs):
    out = run_cli(shimmy_bin, "decode", "--dbc", dbc, "--format", "csv", *logs).stdout
    rows = list(csv.reader(io.StringIO(out)))
    assert rows[0] == ["t", "id", "extended", "msg", "signal", "value"]
    return rows[1:]


def assert_decode_equal(shimmy_bin, dbc, logs):
    reader = sm.decode([str(l) for l in logs], str(dbc))
    assert isinstance(reader, pa.RecordBatchReader)
    assert reader.schema.field("t").type == pa.timestamp("ns", tz="UTC")
    expected = cli_rows(shimmy_bin, dbc, logs)
    n = 0
    batches = 0
    for b in reader:
        batches += 1
        # A batch closes at the first frame boundary from 65,536 rows on (at most 512 signals
        # fit in a 64-byte frame).
        assert b.num_rows < 65536 + 512
        t = b.column("t").cast(pa.int64()).to_pylist()
        cols = [b.column(c).to_pylist() for c in ("id", "extended", "msg", "signal", "value")]
        for i in range(b.num_rows):
            e = expected[n + i]
            got_v = cols[4][i]
            assert [fmt_t(t[i]), str(cols[0][i]), str(cols[1][i]).lower(), cols[2][i], cols[3][i]] == e[:5], (n + i, e)
            if e[5] == "":
                assert not math.isfinite(got_v), (n + i, e, got_v)
            else:
                assert got_v == float(e[5]), (n + i, e, got_v)
        n += b.num_rows
    assert n == len(expected)
    return n, batches


@pytest.mark.parametrize("ext", ["log", "asc", "blf"])
def test_decode_equals_cli_on_the_real_rav4_drive(shimmy_bin, data_dir, ext):
    rows, batches = assert_decode_equal(
        shimmy_bin, data_dir / TOYOTA_DBC, [data_dir / f"{RAV4}.{ext}"]
    )
    # 53,800 frames, most of them of messages the DBC defines: several batches, streamed.
    assert rows > 100_000 and batches >= 2


def test_decode_of_two_logs_is_their_concatenation(shimmy_bin, data_dir):
    log = data_dir / f"{RAV4}.log"
    one = sm.decode(str(log), str(data_dir / TOYOTA_DBC)).read_all()
    two = sm.decode([str(log), str(log)], str(data_dir / TOYOTA_DBC)).read_all()
    assert two.num_rows == 2 * one.num_rows
    assert two.slice(one.num_rows).equals(one)


def test_decode_equals_cli_and_cantools_on_the_vectors(shimmy_bin, data_dir, tmp_path):
    files = sorted(glob.glob(str(data_dir / "vectors" / "*.vectors.jsonl")))
    assert files
    checked = 0
    for f in files:
        stem = os.path.basename(f)[: -len(".vectors.jsonl")]
        dbc = data_dir / "dbc" / "cantools" / f"{stem}.dbc"
        vecs = [json.loads(l) for l in open(f) if l.strip()]
        vecs = [v for v in vecs if "error" not in v and len(v["data"]) <= 16]
        log = tmp_path / f"{stem}.log"
        with open(log, "w") as o:
            for i, v in enumerate(vecs):
                cid = f"{v['frame_id']:08X}" if v["is_extended"] else f"{v['frame_id']:03X}"
                o.write(f"({1 + i * 0.001:.6f}) can0 {cid}#{v['data'].upper()}\n")
        assert_decode_equal(shimmy_bin, dbc, [log])
        # And the values are cantools': per frame (one timestamp each), signal -> value.
        t = sm.decode(str(log), str(dbc)).read_all()
        ts = t.column("t").cast(pa.int64()).to_pylist()
        by_frame = {}
        for tt, s, val in zip(ts, t.column("signal").to_pylist(), t.column("value").to_pylist()):
            by_frame.setdefault(tt, {})[s] = val
        for i, v in enumerate(vecs):
            got = by_frame.get(round((1 + i * 0.001) * 1e6) * 1000, {})
            for name, phys in v["phys"].items():
                if isinstance(phys, (int, float)) and name in got and math.isfinite(phys):
                    assert got[name] == pytest.approx(phys, rel=1e-12, abs=1e-12), (stem, i, name)
                    checked += 1
    assert checked > 1000


def test_estimate_equals_the_cli_json(shimmy_bin, sim_logs):
    for log in sim_logs:
        got = sm.estimate(str(log), "toyota_rav4")
        assert got == cli_estimate(shimmy_bin, "toyota_rav4", [log])
        assert got["profile"] == "toyota_rav4" and got["events_used"] >= 1
    # Several logs, in order: one vehicle's drives.
    got = sm.estimate([str(l) for l in sim_logs], "toyota_rav4")
    assert got == cli_estimate(shimmy_bin, "toyota_rav4", sim_logs)
    assert len(got["events"]) == 12


def test_estimate_with_a_baseline_equals_the_cli_json(shimmy_bin, sim_logs):
    base, log = sim_logs[0], sim_logs[1]
    got = sm.estimate(str(log), "toyota_rav4", baseline=str(base), baseline_clearance_mm=0.05)
    out = run_cli(shimmy_bin, "estimate", "--profile", "toyota_rav4", "--format", "json",
                  "--baseline", base, "--baseline-clearance-mm", "0.05", log)
    assert got == json.loads(out.stdout)
    assert got["baseline"]["clearance_mm"] == 0.05 and got["baseline"]["angle_events"] >= 1
    with pytest.raises(sm.ShimmyError):
        sm.estimate(str(log), "toyota_rav4", baseline=str(base), baseline_clearance_mm=0.0)


def test_export_writes_what_the_cli_writes(shimmy_bin, sim_logs, tmp_path):
    logs = [str(l) for l in sim_logs]
    a, b = tmp_path / "py", tmp_path / "cli"
    s = sm.export(logs, "toyota_rav4", "rav4-7100", a)
    run_cli(shimmy_bin, "export", "--profile", "toyota_rav4", "--vehicle", "rav4-7100", "--out", b, *logs)
    files = lambda d: {str(p.relative_to(d)): p.read_bytes() for p in d.rglob("*") if p.is_file()}
    fa, fb = files(a), files(b)
    assert fa.keys() == fb.keys() and fa == fb
    assert s["files_written"] == len(fa) and s["logs_exported"] == 3 and not s["failed"]
    est = dict(cli_estimate(shimmy_bin, "toyota_rav4", sim_logs))
    est.pop("profile")
    assert s["estimation"] == est
    assert s["events"] == len(est["events"])


def test_events_is_the_lakes_events_table(shimmy_bin, sim_logs, tmp_path):
    ev = sm.events([str(l) for l in sim_logs], "toyota_rav4", vehicle="rav4-7100")
    run_cli(shimmy_bin, "export", "--profile", "toyota_rav4", "--vehicle", "rav4-7100",
            "--out", tmp_path, *sim_logs)
    lake = pq.ParquetDataset(tmp_path / "events").read()  # hive partitions: vehicle, date
    # The same rows (as sets: the dataset reads files in path order).
    rows = lambda t: sorted(
        tuple(str(v) if c in ("vehicle", "date") else v for c, v in r.items())
        for r in t.select(lake.schema.names).to_pylist()
    )
    assert ev.schema.names == lake.schema.names
    assert rows(ev) == rows(lake)
    # The schema events() gives when no event was recorded is the same (the provenance columns
    # included: torque_table_sha256, correction_sha256).
    assert [(f.name, f.type) for f in sm._empty_events().schema] == [
        (f.name, f.type) for f in ev.schema
    ]
    # And in the run's order: the estimate's events.
    est = cli_estimate(shimmy_bin, "toyota_rav4", sim_logs)
    assert ev.column("t_end_s").to_pylist() == [e["t_end"] for e in est["events"]]
    assert ev.num_rows == 12


def test_bad_input_raises_a_clear_error(tmp_path, sim_logs, data_dir, shimmy_bin):
    missing = tmp_path / "nope.log"
    with pytest.raises(sm.ShimmyError, match="nope.log"):
        sm.estimate(str(missing), "toyota_rav4")
    with pytest.raises(sm.ShimmyError, match="nope.log"):
        sm.decode(str(missing), str(data_dir / TOYOTA_DBC))
    with pytest.raises(sm.ShimmyError, match="no_such_car"):
        sm.estimate(str(sim_logs[0]), "no_such_car")
    with pytest.raises(sm.ShimmyError, match="no_such_car"):
        sm.export(str(sim_logs[0]), "no_such_car", "v1", tmp_path / "lake")
    with pytest.raises(sm.ShimmyError):
        sm.decode(str(sim_logs[0]), str(tmp_path / "missing.dbc"))
    corrupt = tmp_path / "corrupt.blf"
    corrupt.write_bytes(b"LOGG" + bytes(range(256)) * 8)
    # A corrupt log, from which no frame can be read: an error naming it, as the CLI gives,
    # and the export reports it failed.
    with pytest.raises(sm.ShimmyError, match="corrupt.blf.*no CAN frame"):
        sm.estimate(str(corrupt), "toyota_rav4")
    cli = run_cli(shimmy_bin, "estimate", "--profile", "toyota_rav4", corrupt, check=False)
    assert cli.returncode != 0 and "corrupt.blf" in cli.stderr and "no CAN frame" in cli.stderr
    with pytest.raises(sm.ShimmyError, match="is a directory|Is a directory|cannot open"):
        sm.estimate(str(tmp_path), "toyota_rav4")
    s = sm.export([str(sim_logs[0]), str(corrupt)], "toyota_rav4", "v1", tmp_path / "lake")
    assert s["logs_exported"] == 1 and [f["log"] for f in s["failed"]] == [str(corrupt)]
    assert "corrupt.blf" in s["failed"][0]["reason"]
    with pytest.raises(sm.ShimmyError, match="corrupt.blf"):
        sm.events([str(sim_logs[0]), str(corrupt)], "toyota_rav4")
    with pytest.raises(sm.ShimmyError, match="vehicle ID"):
        sm.export(str(sim_logs[0]), "toyota_rav4", "../x", tmp_path / "lake")
    with pytest.raises(sm.ShimmyError, match="no logs"):
        sm.estimate([], "toyota_rav4")


def test_fleet_fit_writes_what_the_cli_writes(shimmy_bin, new_joints, tmp_path):
    dirs = [str(d) for d in new_joints["vehicles"]]
    cli_out = tmp_path / "cli.toml"
    cli = run_cli(shimmy_bin, "fleet-fit", "--profile", "toyota_rav4", "-o", cli_out, *dirs)
    out = tmp_path / "py.toml"
    r = sm.fleet_fit(dirs, "toyota_rav4", out)
    assert out.read_bytes() == cli_out.read_bytes()
    assert r["vehicles"] == 5 and r["skipped"] == 0 and r["out"] == str(out)
    c = r["correction"]["angle_deg"]
    assert c["vehicles"] == 5 and c["events"] == 30 and len(c["gain"]) == 3
    assert r["summary"] == [l for l in cli.stdout.splitlines() if l.startswith("angle:")]
    # The plant has no steering column, so its bus carries no torque: said, not fitted.
    assert "torque_nm" not in r["correction"]
    assert any(n.startswith("torque: 0 vehicle(s)") for n in r["not_fitted"])
    # {vehicle: logs} gives the same; an events cache is written and read back unchanged.
    by_id = {os.path.basename(d): sorted(str(p) for p in Path(d).iterdir()) for d in dirs}
    cache = tmp_path / "cache"
    out2 = tmp_path / "py2.toml"
    sm.fleet_fit(by_id, "toyota_rav4", out2, events_cache=cache)
    assert out2.read_bytes() == cli_out.read_bytes()
    cached = {p.name: p.read_bytes() for p in cache.iterdir()}
    assert len(cached) == 5
    sm.fleet_fit(by_id, "toyota_rav4", out2, events_cache=cache)
    assert {p.name: p.read_bytes() for p in cache.iterdir()} == cached
    assert out2.read_bytes() == cli_out.read_bytes()


def test_fleet_fit_refuses_what_it_cannot_fit(new_joints, tmp_path):
    one = [str(new_joints["vehicles"][0])]
    with pytest.raises(sm.ShimmyError, match="at least 2 needed"):
        sm.fleet_fit(one, "toyota_rav4", tmp_path / "c.toml")
    assert not (tmp_path / "c.toml").exists()
    with pytest.raises(sm.ShimmyError, match="neither a log file nor a directory"):
        sm.fleet_fit([str(tmp_path / "nope")], "toyota_rav4", tmp_path / "c.toml")
    with pytest.raises(sm.ShimmyError, match="signal must be"):
        sm.fleet_fit(one * 2, "toyota_rav4", tmp_path / "c.toml", signal="yaw")
    with pytest.raises(sm.ShimmyError, match="clearance"):
        sm.fleet_fit(one * 2, "toyota_rav4", tmp_path / "c.toml", clearance_mm=0.0)
