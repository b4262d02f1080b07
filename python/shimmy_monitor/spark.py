"""The fleet job: many vehicles' CAN logs into one Parquet lake, on Spark.

Input: a manifest naming, per log, the vehicle it came from and the vehicle's profile:

* CSV with a header ``vehicle,profile,log``, or JSON lines ``{"vehicle": ..., "profile": ...,
  "log": ...}`` (extra columns are ignored); each vehicle's logs in time order (the order the
  manifest lists them in is the order they are fed to the monitor);
* or a glob (:func:`manifest_from_glob`): every matching log, the vehicle named by the folder
  holding it, one profile for all.

Log paths must be readable by the executors (a shared file system: NFS, a mounted bucket, DBFS
FUSE, ...); relative paths are resolved against the driver's working directory.

What the job does (:func:`run_fleet`): the manifest's rows are grouped by vehicle
(``groupBy("vehicle").applyInPandas``), and each vehicle's logs are exported on an executor by
:func:`shimmy_monitor.export`, the same code as ``shimmy export``: the signals and the
``events``, ``estimates`` and ``alerts`` tables land in the lake exactly as the CLI would write
them. A log that fails (unreadable, corrupt, another car's bus) or a vehicle whose export cannot
start (unknown profile, bad vehicle ID, several profiles for one vehicle) does not stop the job:
each such log becomes a row of the ``errors`` table, and the other vehicles finish.

Output, besides the lake's own tables:

* ``LAKE/errors/vehicle=<vehicle>/<key16>.parquet``: ``log``, ``reason``, ``profile``,
  ``run_key`` (``key16`` and ``run_key``: the sha256 of the vehicle's manifest rows, so a rerun
  of the same manifest rewrites the same file);
* ``LAKE/fleet_estimates/<manifest16>.parquet``: one row per vehicle (:data:`SUMMARY_COLUMNS`),
  ``manifest16`` the sha256 of the whole manifest;
* the same two as Spark DataFrames, returned.

Everything written is a function of the inputs (no time, host or random name), so running the
job again over the same manifest rewrites identical bytes and adds no file. Files are written
under hidden temporary names and renamed.

From the command line (``spark-submit``; docs/FLEET.md, "Running on a cluster")::

    spark-submit --master yarn shimmy_monitor/spark.py --manifest fleet.csv --lake /data/lake

The same job fits a car model's correction to its profile's tables (:func:`run_fleet_fit`,
``shimmy fleet-fit`` in parallel) from a manifest of its vehicles' drives at new joints::

    spark-submit shimmy_monitor/spark.py --manifest new_joints.csv --fit-correction corr.toml

What this module is not: an estimator or a Parquet writer of its own (both are the Rust
library's, through :mod:`shimmy_monitor`).
"""

from __future__ import annotations

import argparse
import csv
import glob as _glob
import hashlib
import json
import os
import sys
from typing import Dict, Iterator, List, Optional, Sequence, Tuple

import shimmy_monitor as sm

#: Folders the job writes at the lake's root, which a vehicle ID must therefore not take.
RESERVED = ("events", "estimates", "alerts", "errors", "fleet_estimates")

#: Columns of the per-vehicle summary (``fleet_estimates``), as a Spark DDL schema.
SUMMARY_SCHEMA = (
    "vehicle string, profile string, status string, logs int, logs_exported int, "
    "logs_failed int, run_sha256 string, events int, events_used int, clearance_mm double, "
    "interval_lo_mm double, interval_hi_mm double, detectable boolean, below_mm double, "
    "p_clearance_above_threshold double, alerts string, estimate_json string, "
    "errors_json string, worker_maxrss_kib long, seconds double"
)
SUMMARY_COLUMNS = [c.strip().split(" ")[0] for c in SUMMARY_SCHEMA.split(",")]

ERRORS_SCHEMA = "vehicle string, log string, reason string, profile string, run_key string"


# --- the manifest ---------------------------------------------------------------------------


def read_manifest(path: str) -> List[Dict[str, str]]:
    """The manifest's rows (``vehicle``, ``profile``, ``log``, ``seq``: the row's position).

    ``path`` ending in ``.csv``: CSV with a header; otherwise JSON lines. Raises ``ValueError``
    naming the line when a row lacks a field.
    """
    rows: List[Dict[str, str]] = []
    with open(path, newline="", encoding="utf-8") as f:
        if path.endswith(".csv"):
            items = [(i + 2, r) for i, r in enumerate(csv.DictReader(f))]
        else:
            items = [(i + 1, json.loads(l)) for i, l in enumerate(f) if l.strip()]
    for line, r in items:
        missing = [k for k in ("vehicle", "profile", "log") if not r.get(k)]
        if missing:
            raise ValueError(f"{path}:{line}: missing {', '.join(missing)}")
        rows.append(
            {
                "vehicle": str(r["vehicle"]),
                "profile": str(r["profile"]),
                "log": os.path.abspath(str(r["log"])),
                "seq": len(rows),
            }
        )
    return rows


def manifest_from_glob(pattern: str, profile: str) -> List[Dict[str, str]]:
    """A manifest from a glob: each matching file is a log of the vehicle named by the folder
    holding it (``/data/logs/rav4-0042/2026-01-03.log`` → ``rav4-0042``), all of ``profile``;
    logs in name order within a vehicle."""
    rows = []
    for p in sorted(_glob.glob(pattern, recursive=True)):
        if os.path.isfile(p):
            p = os.path.abspath(p)
            rows.append(
                {
                    "vehicle": os.path.basename(os.path.dirname(p)),
                    "profile": profile,
                    "log": p,
                    "seq": len(rows),
                }
            )
    return rows


def _key(parts: Sequence[str]) -> str:
    h = hashlib.sha256()
    h.update(b"shimmy-fleet-1\0")
    for p in parts:
        h.update(p.encode("utf-8"))
        h.update(b"\0")
    return h.hexdigest()


# --- one vehicle, on an executor ------------------------------------------------------------


def _write_parquet(table, dest: str) -> None:
    """Writes ``table`` to ``dest`` through a hidden temporary file, synced, then renamed."""
    import pyarrow.parquet as pq

    os.makedirs(os.path.dirname(dest), exist_ok=True)
    tmp = os.path.join(os.path.dirname(dest), "." + os.path.basename(dest) + ".tmp")
    pq.write_table(table, tmp, compression="snappy")
    with open(tmp, "rb+") as f:
        os.fsync(f.fileno())
    os.replace(tmp, dest)


def process_vehicle(
    vehicle: str,
    rows: List[Dict[str, str]],
    lake: str,
    config: Optional[str] = None,
) -> Tuple[Dict[str, object], List[Dict[str, str]]]:
    """Exports one vehicle's logs (``rows`` of the manifest, in order) to ``lake`` and writes
    its ``errors`` file; returns its summary row and its error rows. Never raises for bad input:
    what fails is in the error rows."""
    import time

    import pyarrow as pa

    t0 = time.monotonic()
    rows = sorted(rows, key=lambda r: int(r["seq"]))
    logs = [r["log"] for r in rows]
    profiles = sorted({r["profile"] for r in rows})
    profile = profiles[0] if len(profiles) == 1 else ",".join(profiles)
    run_key = _key([vehicle, profile] + logs)
    summary: Dict[str, object] = {c: None for c in SUMMARY_COLUMNS}
    summary.update(
        vehicle=vehicle,
        profile=profile,
        logs=len(logs),
        logs_exported=0,
        logs_failed=len(logs),
        status="failed",
    )
    errors: List[Dict[str, str]] = []

    def fail_all(reason: str) -> None:
        for log in logs:
            errors.append({"log": log, "reason": reason})

    if len(profiles) != 1:
        fail_all(f"vehicle {vehicle!r} has logs of several profiles: {', '.join(profiles)}")
    elif vehicle in RESERVED:
        fail_all(f"vehicle ID {vehicle!r} is the name of a lake folder ({', '.join(RESERVED)})")
    else:
        try:
            s = sm.export(logs, profile, vehicle, lake, config=config)
        except sm.ShimmyError as e:
            fail_all(str(e))
        else:
            for f in s["failed"]:
                errors.append({"log": f["log"], "reason": f["reason"]})
            est = s["estimation"]
            lo, hi = (est.get("interval_mm") or [None, None])[:2]
            summary.update(
                status="ok" if not s["failed"] else "partial",
                logs_exported=s["logs_exported"],
                logs_failed=len(s["failed"]),
                run_sha256=s["run_sha256"],
                events=len(est["events"]),
                events_used=est["events_used"],
                clearance_mm=est["clearance_mm"],
                interval_lo_mm=lo,
                interval_hi_mm=hi,
                detectable=est["detectable"],
                below_mm=est["below_mm"],
                p_clearance_above_threshold=est["p_clearance_above_threshold"],
                alerts=",".join(sorted(a["kind"] for a in est["alerts"])),
                estimate_json=json.dumps(est, sort_keys=True),
            )
    if errors:
        t = pa.table(
            {
                "log": [e["log"] for e in errors],
                "reason": [e["reason"] for e in errors],
                "profile": [profile] * len(errors),
                "run_key": [run_key] * len(errors),
            }
        )
        # A vehicle ID that is no folder name cannot have a partition of its own.
        part = vehicle if _safe_folder(vehicle) else "_invalid_" + run_key[:16]
        _write_parquet(
            t, os.path.join(lake, "errors", f"vehicle={part}", f"{run_key[:16]}.parquet")
        )
    summary["errors_json"] = json.dumps(errors)
    summary["worker_maxrss_kib"] = _maxrss_kib()
    summary["seconds"] = time.monotonic() - t0
    return summary, [dict(vehicle=vehicle, profile=profile, run_key=run_key, **e) for e in errors]


def _safe_folder(v: str) -> bool:
    return (
        0 < len(v) <= 64
        and not v.startswith(".")
        and all(c.isascii() and (c.isalnum() or c in "_.-") for c in v)
    )


def _maxrss_kib() -> int:
    import resource

    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)


# --- the job --------------------------------------------------------------------------------


def run_fleet(
    spark,
    manifest: List[Dict[str, str]],
    lake: str,
    config: Optional[str] = None,
    partitions: Optional[int] = None,
):
    """Runs the fleet job; returns ``(summary, errors)`` as Spark DataFrames (one row per
    vehicle, :data:`SUMMARY_SCHEMA`; one row per failed log, :data:`ERRORS_SCHEMA`), and writes
    them into the lake (``fleet_estimates/``, ``errors/``) beside the lake's own tables.

    :param manifest: rows from :func:`read_manifest` or :func:`manifest_from_glob`.
    :param lake: the lake's root, a path every executor can write (shared file system).
    :param config: the monitor's settings (TOML), readable by every executor.
    :param partitions: shuffle partitions for the grouping (default: Spark's parallelism).
    """
    import pyarrow as pa
    import pandas as pd

    lake = os.path.abspath(lake)
    if partitions is None:
        partitions = spark.sparkContext.defaultParallelism
    spark.conf.set("spark.sql.shuffle.partitions", str(partitions))
    df = spark.createDataFrame(
        [(r["vehicle"], r["profile"], r["log"], int(r["seq"])) for r in manifest],
        "vehicle string, profile string, log string, seq long",
    )

    def per_vehicle(pdf: "pd.DataFrame") -> "pd.DataFrame":
        vehicle = str(pdf["vehicle"].iloc[0])
        summary, _ = process_vehicle(vehicle, pdf.to_dict("records"), lake, config)
        return pd.DataFrame([summary], columns=SUMMARY_COLUMNS)

    summary = (
        df.repartition(partitions, "vehicle")
        .groupBy("vehicle")
        .applyInPandas(per_vehicle, schema=SUMMARY_SCHEMA)
    )
    rows = sorted((r.asDict() for r in summary.collect()), key=lambda r: r["vehicle"])
    errors = [
        dict(
            vehicle=r["vehicle"],
            log=e["log"],
            reason=e["reason"],
            profile=r["profile"],
            run_key=_key([r["vehicle"], r["profile"]] + _logs_of(manifest, r["vehicle"])),
        )
        for r in rows
        for e in json.loads(r["errors_json"])
    ]
    # The summary file: everything but the run's own measurements (time, memory), so a rerun
    # writes the same bytes.
    kept = [c for c in SUMMARY_COLUMNS if c not in ("worker_maxrss_kib", "seconds")]
    table = pa.Table.from_pylist([{c: r[c] for c in kept} for r in rows], schema=_summary_arrow(kept))
    mkey = _key([f"{r['vehicle']}\0{r['profile']}\0{r['log']}" for r in manifest])
    _write_parquet(table, os.path.join(lake, "fleet_estimates", f"{mkey[:16]}.parquet"))
    summary_df = spark.createDataFrame(rows, SUMMARY_SCHEMA) if rows else spark.createDataFrame([], SUMMARY_SCHEMA)
    errors_df = spark.createDataFrame(
        [(e["vehicle"], e["log"], e["reason"], e["profile"], e["run_key"]) for e in errors],
        ERRORS_SCHEMA,
    )
    return summary_df, errors_df


def run_fleet_fit(
    spark,
    manifest: List[Dict[str, str]],
    out: str,
    config: Optional[str] = None,
    clearance_mm: float = 0.03,
    signal: Optional[str] = None,
    partitions: Optional[int] = None,
) -> Dict[str, object]:
    """The car model's correction from a fleet at new joints, on Spark: what ``shimmy
    fleet-fit`` does, with the vehicles read in parallel.

    Each vehicle's logs (the manifest's rows, grouped by vehicle as :func:`run_fleet` groups
    them) are read on an executor by :func:`shimmy_monitor.fleet_vehicle_events`, kept in
    ``<out>.events/`` (one file per vehicle, so a stopped job resumes where it was), and the
    fit runs on the driver over the vehicles in the order of their IDs. The file written is
    byte for byte what ``shimmy fleet-fit`` writes given the same vehicles in that order.

    :param manifest: the vehicles' drives at new joints, all of one profile.
    :param out: the correction file (TOML), on a path the driver can write; ``<out>.events/``
        must be writable by every executor.
    :returns: what :func:`shimmy_monitor.fleet_fit` returns.
    :raises ValueError: the manifest is empty or names several profiles.
    :raises ShimmyError: nothing could be fitted (the message says why).
    """
    import pandas as pd

    profiles = sorted({r["profile"] for r in manifest})
    if len(profiles) != 1:
        raise ValueError(
            "a correction is fitted for one car model: the manifest names "
            + (", ".join(profiles) if profiles else "no vehicle")
        )
    profile = profiles[0]
    out = os.path.abspath(out)
    cache = out + ".events"
    if partitions is None:
        partitions = spark.sparkContext.defaultParallelism
    spark.conf.set("spark.sql.shuffle.partitions", str(partitions))
    df = spark.createDataFrame(
        [(r["vehicle"], r["log"], int(r["seq"])) for r in manifest],
        "vehicle string, log string, seq long",
    )

    def per_vehicle(pdf: "pd.DataFrame") -> "pd.DataFrame":
        vehicle = str(pdf["vehicle"].iloc[0])
        logs = [r["log"] for r in sorted(pdf.to_dict("records"), key=lambda r: int(r["seq"]))]
        try:
            ev = sm.fleet_vehicle_events(
                vehicle, logs, profile, config, clearance_mm, signal, events_cache=cache
            )
        except sm.ShimmyError as e:
            # A vehicle that cannot be read is skipped with its reason, as the CLI skips it.
            ev = json.dumps({"key": "", "vehicle": vehicle, "skipped": str(e)})
        return pd.DataFrame([(vehicle, ev)], columns=["vehicle", "events_json"])

    rows = sorted(
        df.repartition(partitions, "vehicle")
        .groupBy("vehicle")
        .applyInPandas(per_vehicle, schema="vehicle string, events_json string")
        .collect(),
        key=lambda r: r["vehicle"],
    )
    for r in rows:
        d = json.loads(r["events_json"])
        if d.get("skipped"):
            print(f"fleet-fit: vehicle {r['vehicle']}: skipped: {d['skipped']}", file=sys.stderr)
    read = [r["events_json"] for r in rows]
    return sm.fleet_fit_events(read, profile, out, config, clearance_mm, signal)


def _logs_of(manifest: List[Dict[str, str]], vehicle: str) -> List[str]:
    return [r["log"] for r in sorted(manifest, key=lambda r: int(r["seq"])) if r["vehicle"] == vehicle]


def _summary_arrow(cols: List[str]):
    import pyarrow as pa

    types = {
        "string": pa.string(),
        "int": pa.int32(),
        "double": pa.float64(),
        "boolean": pa.bool_(),
        "long": pa.int64(),
    }
    spec = dict(
        (c.strip().split(" ")[0], types[c.strip().split(" ")[1]]) for c in SUMMARY_SCHEMA.split(",")
    )
    return pa.schema([(c, spec[c]) for c in cols])


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``spark-submit shimmy_monitor/spark.py --manifest M --lake L`` (or ``--glob G
    --profile P``); prints the per-vehicle summary and the errors; exit status 1 when any log
    failed."""
    ap = argparse.ArgumentParser(prog="shimmy_monitor.spark", description=__doc__.split("\n")[0])
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--manifest", help="CSV (vehicle,profile,log) or JSON lines")
    src.add_argument("--glob", help="logs, the vehicle named by each log's folder")
    ap.add_argument("--profile", help="the profile of every log (with --glob)")
    ap.add_argument("--lake", help="the lake's root (shared file system)")
    ap.add_argument(
        "--fit-correction",
        metavar="OUT",
        help="instead of the lake: fit the car model's correction (shimmy fleet-fit) from the "
        "manifest's vehicles, driven at new joints, into OUT (TOML)",
    )
    ap.add_argument(
        "--clearance-mm", type=float, default=0.03,
        help="with --fit-correction: the joints' clearance during the drives (mm)",
    )
    ap.add_argument(
        "--signal", choices=["angle", "torque"],
        help="with --fit-correction: fit only this signal's table",
    )
    ap.add_argument("--config", help="the monitor's settings (TOML)")
    ap.add_argument("--partitions", type=int, help="shuffle partitions (default: parallelism)")
    ap.add_argument("--master", help="Spark master when not run by spark-submit (e.g. local[2])")
    a = ap.parse_args(argv)
    if a.glob and not a.profile:
        ap.error("--glob needs --profile")
    if bool(a.lake) == bool(a.fit_correction):
        ap.error("give --lake (the fleet job) or --fit-correction OUT (the correction fit)")
    manifest = read_manifest(a.manifest) if a.manifest else manifest_from_glob(a.glob, a.profile)
    from pyspark.sql import SparkSession

    b = SparkSession.builder.appName("shimmy-fleet")
    if a.master:
        b = b.master(a.master)
    spark = b.getOrCreate()
    if a.fit_correction:
        try:
            r = run_fleet_fit(
                spark, manifest, a.fit_correction, a.config, a.clearance_mm, a.signal,
                a.partitions,
            )
        except (ValueError, sm.ShimmyError) as e:
            print(f"shimmy_monitor.spark: error: {e}", file=sys.stderr)
            spark.stop()
            return 1
        for line in r["not_fitted"] + r["summary"]:
            print(line)
        for w in r["warnings"]:
            print(f"shimmy_monitor.spark: warning: {w}", file=sys.stderr)
        print(f"{r['vehicles']} vehicle(s), {r['skipped']} skipped; written to {r['out']}")
        spark.stop()
        return 0
    summary, errors = run_fleet(spark, manifest, a.lake, a.config, a.partitions)
    summary.select(
        "vehicle", "status", "events_used", "clearance_mm", "detectable", "alerts"
    ).orderBy("vehicle").show(n=1 << 20, truncate=False)
    n_err = errors.count()
    if n_err:
        errors.select("vehicle", "log", "reason").show(n=1 << 20, truncate=False)
    spark.stop()
    return 1 if n_err else 0


if __name__ == "__main__":
    sys.exit(main())
