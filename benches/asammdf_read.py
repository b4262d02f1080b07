#!/usr/bin/env python3
"""Peer timing for benches/read_logs.rs: asammdf reads every CAN frame of an MF4 file the way
its users do (MDF(file), then per channel group the bus logging members and the time stamps as
numpy arrays: no per-frame Python). Prints `<frames> <cpu seconds>` (process CPU time, best of
`reps`) for the bench to compare frames per CPU second in the same run.

With `--python-can` as the first argument: python-can's MF4Reader instead (asammdf underneath,
one can.Message per frame, as a Python replay reads frames); it reads only files python-can
wrote."""
import sys
import time

from asammdf import MDF

MEMBERS = ["BusChannel", "ID", "IDE", "DLC", "DataLength", "DataBytes", "EDL", "BRS", "ESI"]


def read(path):
    n = 0
    with MDF(path) as mdf:
        for gi, grp in enumerate(mdf.groups):
            names = {ch.name for ch in grp.channels}
            for prefix in ("CAN_DataFrame", "CAN_RemoteFrame", "CAN_ErrorFrame"):
                got = [f"{prefix}.{m}" for m in MEMBERS if f"{prefix}.{m}" in names]
                if not got:
                    continue
                sigs = mdf.select([(name, gi, None) for name in got])
                n += len(sigs[0].timestamps)
    return n


def read_python_can(path):
    from can.io.mf4 import MF4Reader

    n = 0
    for _ in MF4Reader(path):
        n += 1
    return n


def main():
    global read
    if sys.argv[1] == "--python-can":
        read = read_python_can
        sys.argv.pop(1)
    path, reps = sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 3
    best = None
    for _ in range(reps):
        t0 = time.process_time()
        n = read(path)
        dt = time.process_time() - t0
        best = dt if best is None else min(best, dt)
    print(n, best)


if __name__ == "__main__":
    main()
