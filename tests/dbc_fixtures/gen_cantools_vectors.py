"""Regenerate tests/dbc_fixtures/cantools_extra.vectors.jsonl (used by tests/dbc_decode.rs).

Decodes seeded random payloads (plus all-0x00 / all-0xFF and short payloads) with cantools for
the DBC features the shared vectors do not cover: extended multiplexing (SG_MUL_VAL_, cascaded,
independent multiplexors, value ranges), CAN FD lengths, negative scaling, big numbers.

    pip install cantools==45.1.0
    SHIMMY_DATA_DIR=../shared/data python3 tests/dbc_fixtures/gen_cantools_vectors.py
"""
import json, math, os, random, sys
import cantools

data_dir = os.environ.get("SHIMMY_DATA_DIR", os.path.join(os.path.dirname(__file__), "../../../shared/data"))
FILES = [
    "issue_184_extended_mux_cascaded.dbc",
    "issue_184_extended_mux_independent_multiplexors.dbc",
    "issue_184_extended_mux_multiple_values.dbc",
    "multiplex_2.dbc",
    "multiplex_choices.dbc",
    "fd_test.dbc",
    "issue_636_negative_scaling.dbc",
    "big_numbers.dbc",
    "padding_bit_order.dbc",
]
rng = random.Random(20261122)

def enc(v):
    if isinstance(v, float) and (math.isnan(v) or math.isinf(v)):
        return str(v)
    return v

out = open(os.path.join(os.path.dirname(__file__), "cantools_extra.vectors.jsonl"), "w")
for f in FILES:
    db = cantools.database.load_file(os.path.join(data_dir, "dbc/cantools", f), strict=False)
    for m in db.messages:
        payloads = [bytes(m.length), bytes([0xFF] * m.length)]
        payloads += [bytes(rng.getrandbits(8) for _ in range(m.length)) for _ in range(40)]
        # mux values that cantools accepts: small values in the low bits
        payloads += [bytes([v] + [rng.getrandbits(8) for _ in range(m.length - 1)]) for v in range(8) if m.length]
        for d in payloads:
            rec = {"file": f, "frame_id": m.frame_id, "is_extended": m.is_extended_frame,
                   "name": m.name, "data": d.hex()}
            try:
                raw = m.decode(d, decode_choices=False, scaling=False)
                phys = m.decode(d, decode_choices=False, scaling=True)
                rec["raw"] = {k: enc(v) for k, v in raw.items()}
                rec["phys"] = {k: enc(v) for k, v in phys.items()}
            except Exception as e:
                rec["error"] = f"{type(e).__name__}: {e}"
            out.write(json.dumps(rec) + "\n")
out.close()
