#!/usr/bin/env python3
"""What CubeCL's autotune picked, read from a tune cache, and a pick set by hand.

A tune cache (`PUSHGRASP_TUNE_CACHE`, else ~/.cache/pushgrasp/tune) is a SQLite database,
`default.db`, whose autotune entries are CBOR: per operation (a namespace) and shape (a
key), the index of the fastest candidate and each candidate's outcome and times.

    tools/tune_picks.py list CACHE [--op TEXT]
        each entry: its operation, its key, the candidate picked and the others' median
        times (a GPU's cache tells which candidates made its kernels);
    tools/tune_picks.py force CACHE --op TEXT --candidate NAME [--kernel-size K]
        sets the pick of every entry whose operation contains TEXT (and, for a convolution,
        whose kernel is K x K) to the candidate NAME, where NAME served that shape: a
        software device's cache then runs what a GPU's tuner takes, and a benchmark there
        counts that candidate's kernels (results/gpu.md, "The tuned step's slices").

Run `force` while no process uses the cache. Needs the cbor2 package (pip install cbor2).
"""

import argparse
import sqlite3
import sys
from pathlib import Path

try:
    import cbor2
except ImportError:
    sys.exit("tune_picks.py needs the cbor2 package: pip install cbor2")


def entries(db):
    """(namespace, key bytes, key, value) of every autotune entry."""
    rows = db.execute("select namespace, key, value from entries").fetchall()
    for namespace, key, value in rows:
        if namespace.startswith("autotune/"):
            yield namespace, key, cbor2.loads(key), cbor2.loads(value)


def operation(namespace):
    """The tuned operation: the namespace's last part, burn-cubecl's module path."""
    return namespace.rsplit("/", 1)[-1]


def served(value):
    """Candidate name -> (index, median seconds) for every candidate that served."""
    out = {}
    for result in value["results"]:
        ok = result["outcome"].get("Ok")
        if ok:
            median = ok["computation"]["median"]
            out[ok["name"]] = (ok["index"], median["secs"] + median["nanos"] * 1e-9)
    return out


def picked(value):
    return next(
        (name for name, (index, _) in served(value).items() if index == value["fastest_index"]),
        f"index {value['fastest_index']}",
    )


def kernel_size(key):
    conv = key["key"].get("Conv")
    return conv["kernel_size"] if conv else None


def open_cache(cache):
    path = Path(cache) / "default.db"
    if not path.is_file():
        sys.exit(f"{path}: no tune cache there")
    return sqlite3.connect(path)


def list_picks(args):
    db = open_cache(args.cache)
    for namespace, _, key, value in sorted(entries(db), key=lambda e: operation(e[0])):
        op = operation(namespace)
        if args.op and args.op not in op:
            continue
        times = ", ".join(
            f"{name} {seconds * 1e3:.3f} ms"
            for name, (_, seconds) in sorted(served(value).items(), key=lambda s: s[1][1])
        )
        print(f"{op}: {picked(value)}\n  key {key['key']}\n  served: {times}")


def force(args):
    db = open_cache(args.cache)
    changed = declined = 0
    for namespace, key_bytes, key, value in list(entries(db)):
        if args.op not in operation(namespace):
            continue
        if args.kernel_size and kernel_size(key) != [args.kernel_size] * 2:
            continue
        candidate = served(value).get(args.candidate)
        if candidate is None:
            declined += 1
            continue
        value["fastest_index"] = candidate[0]
        db.execute(
            "update entries set value = ? where namespace = ? and key = ?",
            (cbor2.dumps(value), namespace, key_bytes),
        )
        changed += 1
    db.commit()
    print(f"{changed} entries now pick {args.candidate}; {declined} where it did not serve")
    if changed == 0:
        sys.exit(1)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    listing = commands.add_parser("list", help="each entry's pick and its candidates' times")
    listing.add_argument("cache", help="the tune cache's folder (holds default.db)")
    listing.add_argument("--op", help="only operations whose name contains this")
    listing.set_defaults(run=list_picks)
    forcing = commands.add_parser("force", help="set a candidate as the pick")
    forcing.add_argument("cache", help="the tune cache's folder (holds default.db)")
    forcing.add_argument("--op", required=True, help="operations whose name contains this")
    forcing.add_argument("--candidate", required=True, help="the candidate's name")
    forcing.add_argument("--kernel-size", type=int, help="only convolutions of this kernel")
    forcing.set_defaults(run=force)
    args = parser.parse_args()
    args.run(args)


if __name__ == "__main__":
    main()
