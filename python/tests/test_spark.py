"""The Spark fleet job (shimmy_monitor.spark) on PySpark local[2] over a simulated fleet of 22
vehicles, and the DuckDB queries (python/examples/queries.sql) over the lake it writes.

Checked: each vehicle's estimate and standing alerts equal `shimmy estimate --json` on the
same logs; a corrupt log and a vehicle of an unknown profile land in the errors table while the
others finish; a rerun changes no file of the lake; the queries' answers agree with the CLI
(the vehicles with an open clearance alert are exactly those the CLI raises one for). And the
correction fit (`run_fleet_fit`) on five vehicles at new joints and one unreadable: the file
`shimmy fleet-fit` writes, byte for byte; a rerun reads every vehicle from its cache."""

import hashlib
import importlib.util
import os
import sys
from pathlib import Path

import pyarrow.parquet as pq
import pytest

import shimmy_monitor as sm
from conftest import IN_CI, REPO, cli_estimate

spark_mod = pytest.importorskip("pyspark") if not IN_CI else __import__("pyspark")
from shimmy_monitor import spark as fleet_job  # noqa: E402


def load_queries():
    spec = importlib.util.spec_from_file_location(
        "queries", REPO / "python" / "examples" / "queries.py"
    )
    m = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(m)
    return m


@pytest.fixture(scope="module")
def spark():
    from pyspark.sql import SparkSession

    os.environ["PYSPARK_PYTHON"] = sys.executable
    os.environ["PYSPARK_DRIVER_PYTHON"] = sys.executable
    s = (
        SparkSession.builder.master("local[2]")
        .appName("shimmy-fleet-test")
        .config("spark.ui.enabled", "false")
        .config("spark.sql.shuffle.partitions", "2")
        .config("spark.driver.memory", "1g")
        .getOrCreate()
    )
    s.sparkContext.setLogLevel("ERROR")
    yield s
    s.stop()


def lake_hashes(lake: Path) -> dict:
    return {
        str(p.relative_to(lake)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(lake.rglob("*"))
        if p.is_file()
    }


@pytest.fixture(scope="module")
def job(spark, fleet):
    lake = fleet["dir"] / "lake"
    manifest = fleet_job.read_manifest(str(fleet["manifest"]))
    summary, errors = fleet_job.run_fleet(spark, manifest, str(lake))
    return dict(
        lake=lake,
        manifest=manifest,
        summary={r["vehicle"]: r.asDict() for r in summary.collect()},
        errors=[r.asDict() for r in errors.collect()],
    )


def logs_of(fleet, vehicle):
    return [r["log"] for r in fleet["rows"] if r["vehicle"] == vehicle]


def test_estimates_equal_the_cli(job, fleet, shimmy_bin):
    import json

    summary = job["summary"]
    assert len(summary) == 22
    worn = 0
    for v, row in summary.items():
        if v == "car-unknown":
            continue
        logs = logs_of(fleet, v)
        if v == "car-corrupt":
            logs = [l for l in logs if l != str(fleet["corrupt"])]
        cli = cli_estimate(shimmy_bin, "toyota_rav4", logs)
        cli.pop("profile")
        assert json.loads(row["estimate_json"]) == cli, v
        assert row["events_used"] == cli["events_used"] and row["events_used"] >= 1, v
        assert row["clearance_mm"] == cli["clearance_mm"], v
        assert row["detectable"] == cli["detectable"], v
        assert row["alerts"] == ",".join(sorted(a["kind"] for a in cli["alerts"])), v
        worn += "clearance" in row["alerts"]
        assert row["status"] == ("partial" if v == "car-corrupt" else "ok"), v
    # The fleet holds worn and unworn vehicles (clearance drawn 0.03-0.4 mm).
    assert 0 < worn < 21


def test_failures_land_in_the_errors_table(job, fleet):
    errs = {(e["vehicle"], e["log"]) for e in job["errors"]}
    assert errs == {
        ("car-corrupt", str(fleet["corrupt"])),
        ("car-unknown", str(fleet["unknown"])),
    }
    reasons = {e["vehicle"]: e["reason"] for e in job["errors"]}
    assert "no_such_car" in reasons["car-unknown"]
    assert "b.blf" in reasons["car-corrupt"]
    assert job["summary"]["car-unknown"]["status"] == "failed"
    # Written into the lake too, one file per vehicle.
    t = pq.ParquetDataset(job["lake"] / "errors").read()
    assert sorted(map(str, t.column("vehicle").to_pylist())) == ["car-corrupt", "car-unknown"]
    # The other vehicles finished: their lake files are there.
    vehicles = {p.name for p in job["lake"].iterdir()}
    assert {f"car-{k:02d}" for k in range(20)} | {"car-corrupt"} <= vehicles
    assert "car-unknown" not in vehicles


def test_lake_equals_the_cli_export(job, fleet, shimmy_bin, tmp_path):
    from conftest import run_cli

    v = "car-01"  # two logs
    run_cli(shimmy_bin, "export", "--profile", "toyota_rav4", "--vehicle", v, "--out", tmp_path, *logs_of(fleet, v))
    cli = lake_hashes(tmp_path)
    mine = {k: h for k, h in lake_hashes(job["lake"]).items() if f"vehicle={v}/" in k or k.startswith(f"{v}/")}
    assert cli == mine


def test_rerun_changes_no_file(job, spark, fleet):
    before = lake_hashes(job["lake"])
    fleet_job.run_fleet(spark, job["manifest"], str(job["lake"]))
    assert lake_hashes(job["lake"]) == before


def test_queries_agree_with_the_cli(job, fleet, shimmy_bin):
    q = load_queries().run(str(job["lake"]))
    cols, rows = q["open_clearance_alerts"]
    open_alerts = {r[0] for r in rows}
    expected = {v for v, r in job["summary"].items() if "clearance" in (r["alerts"] or "")}
    assert expected and open_alerts == expected

    cols, rows = q["events_per_day"]
    per_vehicle = {}
    for v, date, n, used in rows:
        assert date == "2026-01-01"  # firmware-sim's drives start then
        per_vehicle[v] = per_vehicle.get(v, 0) + n
    for v, r in job["summary"].items():
        if r["events"] is not None:
            assert per_vehicle[v] == r["events"], v

    cols, rows = q["clearance_trend"]
    trend = {r[0]: dict(zip(cols, r)) for r in rows}
    for v, r in job["summary"].items():
        if r["status"] == "failed":
            assert v not in trend
            continue
        t = trend[v]
        assert t["last_clearance_mm"] == r["clearance_mm"], v
        assert t["last_detectable"] == r["detectable"], v
        assert t["events_used"] == r["events_used"], v


def test_fleet_fit_job_writes_what_the_cli_writes(spark, new_joints, shimmy_bin, tmp_path):
    from conftest import run_cli

    # A sixth vehicle whose only log is not a CAN log: skipped with its reason, counted.
    bad = tmp_path / "nj-bad.log"
    bad.write_bytes(b"not a can log\n")
    manifest = new_joints["manifest"] + [
        dict(vehicle="nj-bad", profile="toyota_rav4", log=str(bad), seq="99")
    ]
    cli_out = tmp_path / "cli.toml"
    # The CLI in the order the job fits: the vehicles' IDs.
    run_cli(shimmy_bin, "fleet-fit", "--profile", "toyota_rav4", "-o", cli_out,
            *[str(v) for v in new_joints["vehicles"]], bad)
    out = tmp_path / "job.toml"
    r = fleet_job.run_fleet_fit(spark, manifest, str(out))
    assert out.read_bytes() == cli_out.read_bytes()
    assert r["vehicles"] == 6 and r["skipped"] == 1
    assert r["correction"]["angle_deg"]["events"] == 30
    cache = Path(str(out) + ".events")
    files = {p.name: p.read_bytes() for p in cache.iterdir()}
    assert len(files) == 6
    # A rerun resumes from the cache: nothing read again, the same file written.
    r2 = fleet_job.run_fleet_fit(spark, manifest, str(out))
    assert {p.name: p.read_bytes() for p in cache.iterdir()} == files
    assert out.read_bytes() == cli_out.read_bytes() and r2["summary"] == r["summary"]
    # One correction is one car model's.
    with pytest.raises(ValueError, match="one car model"):
        fleet_job.run_fleet_fit(
            spark, manifest + [dict(vehicle="x", profile="vw_mqb", log=str(bad), seq="100")],
            str(tmp_path / "mixed.toml"),
        )


def test_fit_correction_from_the_command_line(new_joints, shimmy_bin, tmp_path):
    """`python -m shimmy_monitor.spark --manifest M --fit-correction OUT` (its own Spark, a
    process of its own so the shared session lives on): the CLI's file, its summary printed; a
    manifest of two car models exits 1 with the reason."""
    import csv
    import subprocess

    from conftest import run_cli

    manifest = tmp_path / "new_joints.csv"
    with open(manifest, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["vehicle", "profile", "log"])
        w.writeheader()
        for r in new_joints["manifest"]:
            w.writerow({k: r[k] for k in ("vehicle", "profile", "log")})
    cli_out = tmp_path / "cli.toml"
    run_cli(shimmy_bin, "fleet-fit", "--profile", "toyota_rav4", "-o", cli_out,
            *[str(v) for v in new_joints["vehicles"]])
    out = tmp_path / "job.toml"
    cmd = [sys.executable, "-m", "shimmy_monitor.spark", "--master", "local[1]",
           "--manifest", str(manifest), "--fit-correction", str(out)]
    p = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    assert out.read_bytes() == cli_out.read_bytes()
    assert "angle: rms ×" in p.stdout, p.stdout
    assert f"5 vehicle(s), 0 skipped; written to {out}" in p.stdout, p.stdout

    with open(manifest, "a", newline="") as f:
        csv.writer(f).writerow(["x", "vw_mqb", str(new_joints["vehicles"][1] / "drive.log")])
    p = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600)
    assert p.returncode == 1
    assert "one car model" in p.stderr, p.stderr[-3000:]
