#!/usr/bin/env python3
"""Reads the conformance corpus of the metadata attachment with a Python reader's `decode_meta`.

Usage: check_corpus.py CORPUS [--reader MODULE.py] [--earlier]

CORPUS is crates/ecology-zenoh/tests/corpus/attachments.txt (its header says the format). By
default the reader is this directory's `ecology_peis.decode_meta`, which must read every entry as
the corpus says and refuse the malformed ones. `--reader` takes `decode_meta` from another module
(such as an earlier component); with `--earlier`, only the entries marked `earlier = yes` are
read, as a reader written to the earliest text of version 1 must read them. Prints one line per
entry that disagrees and `N entries read`; exits 1 if any disagreed.
"""

import argparse
import importlib.util
import os
import sys


def entries(path):
    """The corpus as a list of (name, {field: value})."""
    found = []
    with open(path, encoding="utf-8") as corpus:
        for line in corpus:
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            if line.startswith("[") and line.endswith("]"):
                found.append((line[1:-1], {}))
                continue
            field, _, value = line.partition("=")
            found[-1][1][field.strip()] = value.strip()
    return found


def expected(fields):
    """What a reader reads, in decode_meta's terms."""
    optional = lambda name: None if fields[name] == "-" else int(fields[name])
    return dict(seq=int(fields["seq"]), ts_write=int(fields["ts_write"]),
                ts_user=optional("ts_user"), expiry=optional("expiry"),
                expired=fields["expired"] == "yes", epoch=int(fields["epoch"]),
                mimetype=fields["mimetype"],
                creator=None if fields["creator"] == "-" else fields["creator"])


def load_reader(path):
    sys.path.insert(0, os.path.dirname(os.path.abspath(path)))
    spec = importlib.util.spec_from_file_location("reader", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.decode_meta


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("corpus")
    parser.add_argument("--reader", default=os.path.join(os.path.dirname(__file__),
                                                         "ecology_peis.py"))
    parser.add_argument("--earlier", action="store_true")
    args = parser.parse_args()
    decode_meta = load_reader(args.reader)
    wrong, read = [], 0
    for name, fields in entries(args.corpus):
        if args.earlier and fields.get("earlier") != "yes":
            continue
        data = bytes.fromhex("".join(fields["hex"].split()))
        read += 1
        try:
            got = decode_meta(data)
        except ValueError as e:
            if "refused" not in fields:
                wrong.append(f"{name}: refused ({e}), expected it read")
            continue
        if "refused" in fields:
            wrong.append(f"{name}: read as {got}, expected refused ({fields['refused']})")
            continue
        want = expected(fields)
        # A reader need not report fields it does not know (an earlier one has no creator).
        differ = {k: (got[k], v) for k, v in want.items() if k in got and got[k] != v}
        if differ:
            wrong.append(f"{name}: {differ} (read, expected)")
    for line in wrong:
        print(line)
    print(f"{read} entries read, {len(wrong)} disagreed")
    sys.exit(1 if wrong else 0)


if __name__ == "__main__":
    main()
