"""shimmy-monitor from Python.

Brake-induced steering shimmy and steering-joint clearance, estimated from a vehicle's CAN logs
(candump -L, Vector ASC, BLF, ASAM MDF 4, PEAK TRC). Every function here calls the same Rust
code as the ``shimmy`` command it mirrors, so results are those of the CLI:

=========================================  ==============================================
``decode(log, dbc)``                       ``shimmy decode --dbc DBC --format csv LOG``
``estimate(logs, profile)``                ``shimmy estimate --profile P --format json LOG...``
``export(logs, profile, vehicle, out)``    ``shimmy export --profile P --vehicle V --out OUT LOG...``
``events(logs, profile)``                  the ``events`` table ``shimmy export`` writes
``fleet_fit(vehicles, profile, out)``      ``shimmy fleet-fit --profile P -o OUT VEHICLE...``
=========================================  ==============================================

Vehicle profiles (``profile=``) are names under ``config/vehicles`` of the source tree the wheel
was built from, names found in the folders of ``SHIMMY_PROFILES`` (colon-separated) or
``./config/vehicles``, or a path to a profile folder. A DBC a profile names is looked up beside
it, in ``./dbc``, in ``SHIMMY_DBC_PATH`` and in the shared data's ``dbc/opendbc``.

Errors (a missing or unreadable log, an unknown profile, a DBC that does not load) raise
:class:`ShimmyError`, whose message is the whole error chain. The Spark fleet job is
:mod:`shimmy_monitor.spark`; docs/FLEET.md is the manual.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import tempfile
from collections.abc import Mapping
from typing import Iterable, List, Optional, Sequence, Tuple, Union

from . import _native
from ._native import ShimmyError

__all__ = [
    "ShimmyError",
    "decode",
    "estimate",
    "events",
    "export",
    "fleet_fit",
    "fleet_fit_events",
    "fleet_vehicle_events",
    "model_version",
]

PathLike = Union[str, "os.PathLike[str]"]


def _paths(logs: Union[PathLike, Iterable[PathLike]]) -> List[str]:
    if isinstance(logs, (str, bytes, os.PathLike)):
        return [os.fspath(logs)]
    out = [os.fspath(p) for p in logs]
    if not out:
        raise ShimmyError("no logs given")
    return out


def model_version() -> str:
    """The code version every lake row carries: ``shimmy-monitor <version>``."""
    return _native.model_version()


def decode(log: Union[PathLike, Sequence[PathLike]], dbc: PathLike):
    """Decode CAN log(s) with a DBC file, streamed as Arrow record batches.

    :param log: a log file (candump -L, Vector ASC, BLF, ASAM MDF 4 or PEAK TRC, detected from the
        content) or a list of them, read in order.
    :param dbc: the DBC file describing the bus.
    :returns: a ``pyarrow.RecordBatchReader`` with one row per decoded signal, the rows
        ``shimmy decode --format csv`` prints, in the same order:

        ==========  =========================  ==========================================
        column      type                       content
        ==========  =========================  ==========================================
        t           timestamp[ns, tz=UTC]      the frame's timestamp as the log has it
        id          uint32                     CAN ID (without the extended flag)
        extended    bool                       29-bit ID
        msg         string                     DBC message name
        signal      string                     DBC signal name
        value       double                     physical value (raw x factor + offset);
                                               value-table entries stay numbers; a float
                                               signal holding NaN keeps it (the CLI prints
                                               an empty field)
        ==========  =========================  ==========================================

        Left out, as the CLI leaves them out: IDs the DBC does not define, remote and error
        frames, frames whose multiplexer value selects nothing. A batch closes at the first frame
        boundary from 65,536 rows on (a frame's signals are never split), and batches are decoded as they are read, so memory does not grow with the log.
        ``reader.read_all()`` gives a Table, ``reader.read_pandas()`` a DataFrame.
    :raises ShimmyError: the DBC does not load, or a log is missing or not a CAN log. A log
        that breaks while being read raises from the reader (``pyarrow.ArrowException``/
        ``OSError``) with the reason.

    Example::

        import shimmy_monitor as sm
        t = sm.decode("drive.log", "toyota_new_mc_pt_generated.dbc").read_all()
        speed = t.filter(pc.equal(t["signal"], "SPEED"))
    """
    import pyarrow as pa

    handle = _native.decode_stream(_paths(log), os.fspath(dbc))
    return pa.RecordBatchReader._import_from_c(handle.address())


def estimate(
    logs: Union[PathLike, Sequence[PathLike]],
    profile: str,
    config: Optional[PathLike] = None,
    baseline: Union[PathLike, Sequence[PathLike], None] = None,
    baseline_clearance_mm: float = 0.03,
) -> dict:
    """Estimate the steering-joint clearance from one vehicle's logs.

    Exactly ``shimmy estimate --profile PROFILE [--config CONFIG] [--baseline B ...
    --baseline-clearance-mm C] --format json LOG...``: the same Rust code path and the same
    JSON document, returned as a dict (``profile``, ``clearance_mm``, ``interval_mm``,
    ``detectable``, ``below_mm``, ``verdict``, ``events``, ``events_used``, ``rejections``,
    ``p_clearance_above_threshold``, ``alerts``, ``baseline`` when one was given, ...;
    ``shimmy estimate --help`` describes every key).

    :param logs: the vehicle's logs, in time order.
    :param profile: a vehicle profile (name, alias or folder).
    :param config: the monitor's settings (TOML, as config/observer.toml).
    :param baseline: logs of the same vehicle driven at a known clearance (its first drives
        after a joint replacement); their braking events condition the estimate.
    :param baseline_clearance_mm: the joints' clearance during the baseline logs (mm).
    :raises ShimmyError: unknown profile, a log that is missing or cannot be read, a baseline
        without a usable braking event.
    """
    return json.loads(
        _native.estimate_json(
            _paths(logs),
            profile,
            None if config is None else os.fspath(config),
            [] if baseline is None else _paths(baseline),
            float(baseline_clearance_mm),
        )
    )


def export(
    logs: Union[PathLike, Sequence[PathLike]],
    profile: str,
    vehicle: str,
    out: PathLike,
    config: Optional[PathLike] = None,
    signals: bool = True,
) -> dict:
    """Export one vehicle's logs to the Parquet fleet lake, as ``shimmy export`` does.

    Writes under ``out`` the decoded signals (``<vehicle>/<message>/<yyyy>/<mm>/<dd>/``) and
    the monitor's ``events``, ``estimates`` and ``alerts`` tables (Hive partitions
    ``vehicle=``/``date=``); docs/FLEET.md lists every column. Names and bytes come from the
    content, so exporting the same logs again rewrites identical files and adds none.

    :param signals: ``False`` writes only the monitor's tables (the same files as a full export).
    :returns: the run's summary: ``lake``, ``vehicle``, ``profile``, ``run_sha256``, ``logs``,
        ``logs_exported``, ``failed`` (a list of ``{"log", "reason"}``: logs that could not be
        read, hold no CAN frame, or carry none of the profile's messages; the others are still
        exported), ``frames``, ``mapped_frames``, ``files_written``, ``events``,
        ``alerts_standing``, and ``estimation``: the estimate at the end of the run (the dict
        :func:`estimate` returns over the logs that reached the monitor, without ``profile``).
    :raises ShimmyError: the run cannot start (unknown profile, bad vehicle ID, unwritable
        lake) or a file cannot be written. A failing log does not raise; see ``failed``.
    """
    return json.loads(
        _native.export_json(
            _paths(logs),
            profile,
            vehicle,
            os.fspath(out),
            None if config is None else os.fspath(config),
            signals,
        )
    )


def events(
    logs: Union[PathLike, Sequence[PathLike]],
    profile: str,
    vehicle: str = "vehicle",
    config: Optional[PathLike] = None,
):
    """The braking events of one vehicle's logs, as the lake's ``events`` table.

    Runs the export's pipeline writing only the monitor's tables, into a temporary folder, and
    reads its ``events`` table back, so the rows and columns are exactly the lake's (``t``,
    ``t_start_s``, ``t_end_s``, ``v0_kmh``, ``decel_g``, ``peak_sw_bp_deg``,
    ``sw_amplitude_deg``, ``used``, ``unused_reason``, ``odometer_km`` and the provenance
    columns), plus the partition columns ``vehicle`` and ``date`` (string), in the run's order
    (the logs' order, then the events' within a log: the order of ``estimate()["events"]``).

    :returns: a ``pyarrow.Table`` (empty, with the schema, when no event was recorded).
    :raises ShimmyError: as :func:`export`, and when any log failed (the reasons listed).
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    with tempfile.TemporaryDirectory(prefix="shimmy-events-") as tmp:
        s = export(logs, profile, vehicle, tmp, config=config, signals=False)
        if s["failed"]:
            raise ShimmyError(
                "; ".join(f"{f['log']}: {f['reason']}" for f in s["failed"])
            )
        root = os.path.join(tmp, "events")
        # events/vehicle=V/date=D/<run16>-<nnnn>.parquet: the run's order is the log position
        # nnnn (and within a log, the date), not the timestamp (two logs may overlap in time).
        files = []
        for dirpath, _, names in os.walk(root):
            for n in names:
                if n.endswith(".parquet") and not n.startswith("."):
                    date = os.path.basename(dirpath).split("=", 1)[1]
                    files.append((n.rsplit("-", 1)[1], date, os.path.join(dirpath, n)))
        if not files:
            return _empty_events()
        parts = []
        for _, date, path in sorted(files):
            t = pq.read_table(path)
            t = t.append_column("vehicle", pa.array([vehicle] * t.num_rows, pa.string()))
            parts.append(t.append_column("date", pa.array([date] * t.num_rows, pa.string())))
        return pa.concat_tables(parts)


def _vehicle_logs(v: PathLike) -> List[str]:
    """A vehicle given as a path: the log file, or the files of the folder in name order (as
    ``shimmy fleet-fit`` reads it)."""
    return [os.fspath(p) for p in _native.fleet_vehicle_logs(os.fspath(v))]


def _fit_cache_file(cache: str, vehicle: str, logs: Sequence[str]) -> str:
    """The events cache's file of one vehicle: named by its ID and logs, so a vehicle whose logs
    change gets read again (the file also keeps their sizes and times)."""
    h = hashlib.sha256("\0".join([vehicle, *logs]).encode()).hexdigest()[:16]
    return os.path.join(cache, f"{h}.json")


def fleet_vehicle_events(
    vehicle: str,
    logs: Union[PathLike, Sequence[PathLike]],
    profile: str,
    config: Optional[PathLike] = None,
    clearance_mm: float = 0.03,
    signal: Optional[str] = None,
    events_cache: Optional[PathLike] = None,
) -> str:
    """One vehicle's braking events at new joints, read as :func:`fleet_fit` reads them: an
    opaque JSON string for :func:`fleet_fit_events`. The fleet job calls it on its executors.

    :param events_cache: a folder where the result is kept (one file per vehicle) and read back
        while the vehicle's logs are unchanged, so a stopped job resumes.
    """
    logs = _paths(logs)
    cache = None
    if events_cache is not None:
        cache = _fit_cache_file(os.fspath(events_cache), vehicle, logs)
    return _native.fleet_fit_vehicle_json(
        vehicle,
        logs,
        profile,
        None if config is None else os.fspath(config),
        float(clearance_mm),
        signal,
        cache,
    )


def fleet_fit_events(
    vehicles: Sequence[str],
    profile: str,
    out: PathLike,
    config: Optional[PathLike] = None,
    clearance_mm: float = 0.03,
    signal: Optional[str] = None,
) -> dict:
    """The fit of :func:`fleet_fit` over vehicles read by :func:`fleet_vehicle_events` (in the
    order given); writes ``out`` and returns what :func:`fleet_fit` returns."""
    r = json.loads(
        _native.fleet_fit_json(
            profile,
            list(vehicles),
            os.fspath(out),
            None if config is None else os.fspath(config),
            float(clearance_mm),
            signal,
        )
    )
    r["out"] = os.fspath(out)
    return r


def fleet_fit(
    vehicles: Union[Mapping[str, Union[PathLike, Sequence[PathLike]]], Iterable[PathLike]],
    profile: str,
    out: PathLike,
    clearance_mm: float = 0.03,
    config: Optional[PathLike] = None,
    signal: Optional[str] = None,
    events_cache: Optional[PathLike] = None,
) -> dict:
    """Fit a car model's correction to its profile's response tables from many of its vehicles
    driven at new joints, as ``shimmy fleet-fit`` does (``shimmy fleet-fit --help`` is the
    manual; docs/ACCURACY.md, "The car model's correction", what it takes out and what not).

    Each vehicle's logs go through the same pipeline as :func:`estimate` with a baseline; the
    fit finds, per steering signal the profile has a table of, a gain per feature (braking RMS,
    peak, cruise RMS), its standard error and the vehicles' spread about it. Name the file
    written in the profile's profile.toml as ``correction = "<file>"``: every estimate from the
    profile (CLI, shimmyd, this package, the fleet job) then applies it.

    :param vehicles: ``{vehicle_id: logs}`` (a log or a list of them, in time order), or paths,
        one per vehicle: a log file, or a folder whose files are the vehicle's logs (name order).
        The fit takes them in this order; the same vehicles in the same order write the same
        bytes as the CLI.
    :param out: the correction file to write (TOML).
    :param clearance_mm: the joints' clearance during the drives (new joints: 0.02-0.06 mm).
    :param signal: ``"angle"`` or ``"torque"`` to fit only that signal's table.
    :param events_cache: a folder keeping each vehicle's events as it is read (resume).
    :returns: ``correction`` (the file's content as a dict: ``angle_deg``/``torque_nm`` with
        ``gain``, ``gain_se_ln``, ``spread_ln``, ``gains_agree_p``, ``vehicles``, ``events``,
        ...), ``summary`` (a line per signal fitted), ``not_fitted`` (signals left out, with
        why), ``warnings`` (signals whose features' gains disagree: the car differs from the
        model by more than a gain, and the correction should not be shipped), ``vehicles``,
        ``skipped`` (vehicles without a usable braking event) and ``out``.
    :raises ShimmyError: unknown profile, a missing log, or nothing could be fitted (too few
        vehicles with events, a sensor noisier than its table: the message says which).
    """
    if isinstance(vehicles, Mapping):
        items: List[Tuple[str, List[str]]] = [(str(k), _paths(v)) for k, v in vehicles.items()]
    else:
        if isinstance(vehicles, (str, bytes, os.PathLike)):
            vehicles = [vehicles]
        items = [(os.fspath(v), _vehicle_logs(v)) for v in vehicles]
    if not items:
        raise ShimmyError("no vehicles given")
    read = []
    for i, (v, logs) in enumerate(items):
        e = fleet_vehicle_events(v, logs, profile, config, clearance_mm, signal, events_cache)
        d = json.loads(e)
        what = f"skipped: {d['skipped']}" if d.get("skipped") else f"{len(d['evidence'])} event(s)"
        print(f"fleet_fit: vehicle {i + 1}/{len(items)} {v}: {what}", file=sys.stderr)
        read.append(e)
    return fleet_fit_events(read, profile, out, config, clearance_mm, signal)


def _empty_events():
    import pyarrow as pa

    ts = pa.timestamp("us", tz="UTC")
    f64 = pa.float64()
    return pa.schema(
        [
            ("t", ts),
            ("t_start_s", f64),
            ("t_end_s", f64),
            ("v0_kmh", f64),
            ("decel_g", f64),
            ("peak_sw_bp_deg", f64),
            ("sw_amplitude_deg", f64),
            ("used", pa.bool_()),
            ("unused_reason", pa.string()),
            ("odometer_km", f64),
            ("peak_torque_bp_nm", f64),
            ("torque_used", pa.bool_()),
            ("log_blake3", pa.string()),
            ("run_sha256", pa.string()),
            ("model_version", pa.string()),
            ("table_sha256", pa.string()),
            ("dbc_sha256", pa.string()),
            ("torque_table_sha256", pa.string()),
            ("correction_sha256", pa.string()),
            ("vehicle", pa.string()),
            ("date", pa.string()),
        ]
    ).empty_table()
