"""Optional cross-check input for tests/dbc_cantools_all.rs (an #[ignore]d test): decodes
random, all-0x00 and all-0xFF payloads of every message of every DBC under dbc/ that cantools
itself can load, with cantools, into a JSON-lines file (about 12,000 frames, 6 MB).

    pip install cantools==45.1.0
    python3 tests/dbc_fixtures/gen_cantools_all.py DATA_DIR OUT.jsonl
    SHIMMY_CANTOOLS_ALL=OUT.jsonl cargo test --release --test dbc_cantools_all -- --ignored
"""
import sys
import json, math, os, random, glob
data_dir, out_path = sys.argv[1], sys.argv[2]
import cantools
rng = random.Random(7)
def enc(v):
    if isinstance(v, float) and (math.isnan(v) or math.isinf(v)): return str(v)
    return v
out = open(out_path, 'w')
for path in sorted(glob.glob(os.path.join(data_dir, 'dbc/*/*.dbc')) + glob.glob(os.path.join(data_dir, 'dbc/*/*.DBC'))):
    try:
        db = cantools.database.load_file(path, strict=False)
    except Exception as e:
        print("cantools cannot load", path, type(e).__name__, str(e)[:100]); continue
    for m in db.messages:
        n = 6 if len(db.messages) > 100 else 20
        pls = [bytes(m.length), bytes([0xFF]*m.length)] + [bytes(rng.getrandbits(8) for _ in range(m.length)) for _ in range(n)]
        for d in pls:
            rec = {"path": os.path.relpath(path, data_dir), "frame_id": m.frame_id, "is_extended": m.is_extended_frame, "name": m.name, "data": d.hex()}
            try:
                raw = m.decode(d, decode_choices=False, scaling=False)
                phys = m.decode(d, decode_choices=False, scaling=True)
                rec["raw"] = {k: enc(v) for k, v in raw.items()}
                rec["phys"] = {k: enc(v) for k, v in phys.items()}
            except Exception as e:
                rec["error"] = f"{type(e).__name__}: {e}"
            out.write(json.dumps(rec) + "\n")
