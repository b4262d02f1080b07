#!/usr/bin/env python3
"""Reference side of the decode benchmark (benches/decode.rs runs it): read a candump -L log
line by line and decode every frame with cantools, the way a cantools user would.

    python3 benches/cantools_decode.py DBC LOG

Prints one JSON object: frames read, frames decoded, frames cantools refused or did not know,
and the wall time of the read+decode loop (DBC loading excluded, as on the Rust side).
"""
import json
import sys
import time

import cantools


def main():
    dbc, log = sys.argv[1], sys.argv[2]
    t0 = time.perf_counter()
    db = cantools.database.load_file(dbc, strict=False)
    load_s = time.perf_counter() - t0
    frames = decoded = unknown = errors = malformed = 0
    checksum = 0.0
    t0, c0 = time.perf_counter(), time.process_time()
    with open(log, "r") as f:
        for line in f:
            parts = line.split()
            if len(parts) < 3 or not parts[0].startswith("("):
                continue
            try:
                ident, payload = parts[2].split("#", 1)
                frame_id = int(ident, 16)
                data = bytes.fromhex(payload)
            except ValueError:
                malformed += 1
                continue
            frames += 1
            try:
                sig = db.decode_message(frame_id, data, decode_choices=False)
            except KeyError:
                unknown += 1
                continue
            except Exception:
                errors += 1
                continue
            decoded += 1
            for v in sig.values():
                checksum += v
    loop_s = time.perf_counter() - t0
    cpu_s = time.process_time() - c0
    print(json.dumps({
        "cantools_version": cantools.__version__,
        "frames": frames,
        "decoded": decoded,
        "unknown": unknown,
        "errors": errors,
        "malformed": malformed,
        "load_s": load_s,
        "seconds": loop_s,
        "cpu_seconds": cpu_s,
        "frames_per_s": frames / loop_s if loop_s > 0 else 0.0,
        "checksum": checksum,
    }))


if __name__ == "__main__":
    main()
