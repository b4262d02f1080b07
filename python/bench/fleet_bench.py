"""Throughput and memory of the Spark fleet job (shimmy_monitor.spark) on local[N].

    python python/bench/fleet_bench.py --firmware-sim target/release/firmware-sim \\
        --vehicles 40 --events 10 --masters 'local[1]' 'local[2]'

Simulates a fleet with firmware-sim (toyota_rav4, candump logs, one per vehicle), then for each
master: starts a Spark session, warms it up on 2 vehicles, and times run_fleet over the whole
fleet into a fresh lake (the timed part: grouping, the exports on the executors, collecting the
summary, writing fleet_estimates). Prints vehicles/minute and the Python workers' peak RSS
(ru_maxrss of the worker process after its task: the Rust export plus the worker's pandas and
pyarrow; the JVM is not counted), one line per master.
"""

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--firmware-sim", required=True)
    ap.add_argument("--vehicles", type=int, default=40)
    ap.add_argument("--events", type=int, default=10)
    ap.add_argument("--masters", nargs="+", default=["local[1]", "local[2]"])
    ap.add_argument("--work", help="scratch folder (default: a temporary one)")
    a = ap.parse_args()

    os.environ["PYSPARK_PYTHON"] = sys.executable
    os.environ["PYSPARK_DRIVER_PYTHON"] = sys.executable
    from pyspark.sql import SparkSession

    from shimmy_monitor import spark as job

    work = a.work or tempfile.mkdtemp(prefix="shimmy-fleet-bench-")
    sim = os.path.join(work, "sim")
    subprocess.run(
        [a.firmware_sim, "fleet", "--profile", "toyota_rav4", "--vehicles", str(a.vehicles),
         "--events", str(a.events), "--seed-base", "9000", "--logs-only", "--work-dir", sim],
        check=True, capture_output=True,
    )
    logs = sorted(p for p in os.listdir(sim) if p.endswith(".log"))
    size = sum(os.path.getsize(os.path.join(sim, p)) for p in logs)
    manifest = [
        dict(vehicle=f"v{i:04d}", profile="toyota_rav4", log=os.path.join(sim, p), seq=i)
        for i, p in enumerate(logs)
    ]
    print(f"fleet: {len(logs)} vehicles x {a.events} events, {size / 1e6:.1f} MB of candump")
    for master in a.masters:
        spark = (
            SparkSession.builder.master(master).appName("shimmy-fleet-bench")
            .config("spark.ui.enabled", "false").getOrCreate()
        )
        spark.sparkContext.setLogLevel("ERROR")
        warm = os.path.join(work, "lake-warm")
        job.run_fleet(spark, manifest[:2], warm)
        lake = os.path.join(work, "lake-" + master.replace("[", "").replace("]", ""))
        shutil.rmtree(lake, ignore_errors=True)
        t0 = time.monotonic()
        summary, errors = job.run_fleet(spark, manifest, lake)
        rows = summary.collect()
        dt = time.monotonic() - t0
        assert errors.count() == 0 and len(rows) == len(manifest)
        rss = [r["worker_maxrss_kib"] for r in rows]
        task_s = [r["seconds"] for r in rows]
        print(
            f"{master}: {len(rows)} vehicles in {dt:.1f} s = {60 * len(rows) / dt:.0f} vehicles/min; "
            f"per vehicle task {statistics.median(task_s):.2f} s median; "
            f"worker peak RSS {max(rss) / 1024:.0f} MiB max, {statistics.median(rss) / 1024:.0f} MiB median"
        )
        spark.stop()
    if not a.work:
        shutil.rmtree(work)


if __name__ == "__main__":
    main()
