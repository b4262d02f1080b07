"""Runs the DuckDB queries of queries.sql over a fleet lake and prints them.

    python python/examples/queries.py LAKE            # every query
    python python/examples/queries.py LAKE open_clearance_alerts

As a library: ``run(lake)`` returns ``{name: (columns, rows)}``; ``QUERIES`` maps each query's
name to its SQL (``{lake}`` to be replaced by the lake's root).
"""

import os
import re
import sys
from typing import Dict, List, Tuple

HERE = os.path.dirname(os.path.abspath(__file__))


def load(path: str = os.path.join(HERE, "queries.sql")) -> Dict[str, str]:
    """The queries of a .sql file, by the name in their ``-- name:`` line."""
    text = open(path, encoding="utf-8").read()
    out = {}
    for block in re.split(r"^-- name: ", text, flags=re.M)[1:]:
        name, sql = block.split("\n", 1)
        out[name.strip()] = sql.strip()
    return out


QUERIES = load()


def run(lake: str, names=None, con=None) -> Dict[str, Tuple[List[str], List[tuple]]]:
    import duckdb

    con = con or duckdb.connect()
    lake = os.path.abspath(lake).replace("'", "''")
    out = {}
    for name, sql in QUERIES.items():
        if names and name not in names:
            continue
        cur = con.execute(sql.replace("{lake}", lake))
        out[name] = ([d[0] for d in cur.description], cur.fetchall())
    return out


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    for name, (cols, rows) in run(sys.argv[1], sys.argv[2:] or None).items():
        print(f"-- {name}")
        print("\t".join(cols))
        for r in rows:
            print("\t".join("" if v is None else str(v) for v in r))
        print()
