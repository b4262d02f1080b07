#!/usr/bin/env python3
"""Reference side of the MF4 tests (tests/logs_mf4_asammdf.rs): asammdf reads and writes MDF 4,
python-can's MF4Writer writes it. One run executes a job file, one job per line:

  dump IN OUT.csv          every CAN frame asammdf reads in IN, one row per frame in group order:
                           group,kind,t,bus,id,ide,dlc,data_hex,edl,brs,esi
                           (t = repr of asammdf's float timestamp, seconds from the file's start;
                           bus = BusChannel, raw when a value-to-text conversion names it;
                           data_hex = the DataBytes the DLC covers, as for the real files' CSVs)
  pycan IN.log OUT.mf4 L   python-can: read a candump -L log, write MF4Writer(compression_level=L)
  resave IN OUT.mf4 L      asammdf: MDF(IN).save(OUT, compression=L)

Exits 3 with a message when asammdf or python-can is missing (the test decides to skip or fail).
"""
import sys

try:
    import numpy as np
    from asammdf import MDF
    import can
    from can.io.mf4 import MF4Writer
except ImportError as e:  # pragma: no cover
    print(f"missing Python module: {e}", file=sys.stderr)
    sys.exit(3)

FD_LEN = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64]
KINDS = {"CAN_DataFrame": "D", "CAN_RemoteFrame": "R", "CAN_ErrorFrame": "E"}


def numeric(sig, raw_sig):
    s = sig.samples
    if s.dtype.kind in "iuf" and s.dtype.names is None:
        return s
    return raw_sig.samples


def dump(path, out):
    mdf = MDF(path)
    rows = []
    for gi, grp in enumerate(mdf.groups):
        names = [ch.name for ch in grp.channels]
        prefix = next((n.split(".")[0] for n in names if n.split(".")[0] in KINDS and "." in n), None)
        if prefix is None:
            continue
        if grp.channel_group.cycles_nr == 0 and not mdf.get(names[0], group=gi).timestamps.size:
            continue
        acq = grp.channel_group.acq_name or prefix

        def get(member, raw=False):
            name = f"{prefix}.{member}"
            if name not in names:
                return None
            sig = mdf.get(name, group=gi, raw=raw)
            return sig

        ts = None
        cols = {}
        for m in ["BusChannel", "ID", "IDE", "DLC", "DataLength", "EDL", "BRS", "ESI"]:
            s = get(m)
            if s is None:
                continue
            ts = s.timestamps
            cols[m] = numeric(s, get(m, raw=True)) if m == "BusChannel" else s.samples
        data = get("DataBytes")
        if data is not None:
            ts = data.timestamps
        if ts is None:
            continue
        kind = KINDS[prefix]
        n = len(ts)
        for i in range(n):
            col = lambda m, d=0: int(cols[m][i]) if m in cols else d
            raw_id = col("ID")
            ide = col("IDE", 1 if raw_id > 0x7FF else 0) or (1 if raw_id & 0x80000000 else 0)
            edl = col("EDL") if kind == "D" else 0
            dlc = col("DLC", -1)
            payload = b""
            if data is not None:
                payload = bytes(np.asarray(data.samples[i]).tobytes())
            if dlc < 0:
                dlc = col("DataLength", len(payload))
            want = FD_LEN[min(dlc, 15)] if edl else min(dlc, 8)
            if kind == "D":
                payload = payload[:want]
            elif kind == "E":
                payload = payload[:8]
            else:
                payload = b""
            rows.append(
                f"{acq},{kind},{float(ts[i])!r},{col('BusChannel', 1)},{raw_id & 0x1FFFFFFF},{ide},"
                f"{dlc},{payload.hex().upper()},{edl},{col('BRS')},{col('ESI')}"
            )
    mdf.close()
    with open(out, "w") as f:
        f.write("group,kind,t,bus,id,ide,dlc,data_hex,edl,brs,esi\n")
        for r in rows:
            f.write(r + "\n")


def pycan(log, out, level):
    w = MF4Writer(out, compression_level=int(level))
    with can.LogReader(log) as r:
        for m in r:
            w.on_message_received(m)
    w.stop()


def resave(src, out, level):
    mdf = MDF(src)
    mdf.save(out, compression=int(level), overwrite=True)
    mdf.close()


def main():
    for line in open(sys.argv[1]):
        job = line.split()
        if not job:
            continue
        {"dump": dump, "pycan": pycan, "resave": resave}[job[0]](*job[1:])


if __name__ == "__main__":
    main()
