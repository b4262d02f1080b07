-- DuckDB queries over the fleet lake (docs/FLEET.md). `{lake}` is the lake's root; run them with
-- python/examples/queries.py LAKE (which substitutes it), or paste them into the duckdb shell.
--
-- The monitor's tables keep every export run's rows apart (run_sha256). These queries read the
-- runs the Spark job's per-vehicle summaries name (fleet_estimates/), i.e. the current estimate
-- of each vehicle over all its logs.

-- name: current_runs
-- One row per vehicle: the run the fleet job's summary names.
SELECT DISTINCT vehicle, run_sha256
FROM read_parquet('{lake}/fleet_estimates/*.parquet')
WHERE run_sha256 IS NOT NULL
ORDER BY vehicle;

-- name: open_clearance_alerts
-- Vehicles with an open clearance alert: per alert, the last transition of the current run is
-- not `cleared`.
WITH runs AS (
    SELECT DISTINCT vehicle, run_sha256 FROM read_parquet('{lake}/fleet_estimates/*.parquet')
),
tr AS (
    SELECT a.*, row_number() OVER (
        PARTITION BY a.vehicle, a.run_sha256, a.alert_id
        ORDER BY a.t_event_end_s DESC, a.updates DESC,
                 CASE a.transition WHEN 'cleared' THEN 2 WHEN 'updated' THEN 1 ELSE 0 END DESC
    ) AS k
    FROM read_parquet('{lake}/alerts/*/*/*.parquet', hive_partitioning = true) a
    JOIN runs USING (vehicle, run_sha256)
)
SELECT vehicle, alert_id, t_raised_s, t_updated_s, updates, summary
FROM tr
WHERE k = 1 AND kind = 'clearance' AND transition <> 'cleared'
ORDER BY vehicle;

-- name: clearance_trend
-- Clearance trend per vehicle: the estimate after each braking event of the current run, and
-- the least-squares slope of the posterior median over the odometer (mm per 1000 km; null
-- where fewer than two estimates were detectable). first/last: of the first and last event, null
-- when that estimate was not detectable (arg_*_null keeps nulls).
WITH runs AS (
    SELECT DISTINCT vehicle, run_sha256 FROM read_parquet('{lake}/fleet_estimates/*.parquet')
),
est AS (
    SELECT e.vehicle, e.t, e.t_event_end_s, e.clearance_mm, e.detectable, e.events_used,
           ev.odometer_km
    FROM read_parquet('{lake}/estimates/*/*/*.parquet', hive_partitioning = true) e
    JOIN runs USING (vehicle, run_sha256)
    LEFT JOIN read_parquet('{lake}/events/*/*/*.parquet', hive_partitioning = true) ev
      ON ev.vehicle = e.vehicle AND ev.run_sha256 = e.run_sha256 AND ev.t_end_s = e.t_event_end_s
)
SELECT vehicle,
       count(*) AS estimates,
       arg_min_null(clearance_mm, t_event_end_s) AS first_clearance_mm,
       arg_max_null(clearance_mm, t_event_end_s) AS last_clearance_mm,
       arg_max_null(detectable, t_event_end_s) AS last_detectable,
       max(events_used) AS events_used,
       1000 * regr_slope(clearance_mm, odometer_km) AS slope_mm_per_1000km
FROM est
GROUP BY vehicle
ORDER BY vehicle;

-- name: events_per_day
-- Braking events per vehicle and day (UTC, of the event's end) in the current run, and how
-- many the estimate used.
WITH runs AS (
    SELECT DISTINCT vehicle, run_sha256 FROM read_parquet('{lake}/fleet_estimates/*.parquet')
)
SELECT vehicle, CAST(date AS VARCHAR) AS date, count(*) AS events, count_if(used) AS used
FROM read_parquet('{lake}/events/*/*/*.parquet', hive_partitioning = true)
JOIN runs USING (vehicle, run_sha256)
GROUP BY vehicle, date
ORDER BY vehicle, date;
