"""shimmy-monitor from Python.

Brake-induced steering shimmy and steering-joint clearance, estimated from a vehicle's CAN logs
(candump -L, Vector ASC, BLF, ASAM MDF 4, PEAK TRC). Every function here calls the same Rust
code as the ``shimmy`` command it mirrors, so results are those of the CLI:

=========================================  ==============================================
``decode(log, dbc)``                       ``shimmy decode --dbc DBC --format csv LOG``
``estimate(logs, profile)``                ``shimmy estimate --profile P --format json LOG...``
``export(logs, profile, vehicle, out)``    ``shimmy export --profile P --vehicle V --out OUT LOG...``
``events(logs, profile)``                  the ``events`` table ``shimmy export`` writes
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

import json
import os
import tempfile
from typing import Iterable, List, Optional, Sequence, Union

from . import _native
from ._native import ShimmyError

__all__ = [
    "ShimmyError",
    "decode",
    "estimate",
    "events",
    "export",
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
