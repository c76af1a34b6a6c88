#!/usr/bin/env python3
"""Are two material directories the same fit? Every file byte for byte, but
material.json, which is compared less its timings (keys ending in `_s` or
naming seconds), as two runs of one fit never share them.

    python3 scripts/same-material.py A B

Prints "identical" or the files that differ; exit status 1 if any differs.
"""
import filecmp
import json
import os
import sys


def untimed(o):
    if isinstance(o, dict):
        return {k: untimed(v) for k, v in o.items() if not (k.endswith("_s") or "seconds" in k)}
    if isinstance(o, list):
        return [untimed(v) for v in o]
    return o


def differing(a, b):
    files = sorted(set(os.listdir(a)) | set(os.listdir(b)))
    differ = []
    for f in files:
        pa, pb = os.path.join(a, f), os.path.join(b, f)
        if not (os.path.exists(pa) and os.path.exists(pb)):
            differ.append(f)
        elif f.endswith(".json"):
            with open(pa) as x, open(pb) as y:
                if untimed(json.load(x)) != untimed(json.load(y)):
                    differ.append(f)
        elif not filecmp.cmp(pa, pb, shallow=False):
            differ.append(f)
    return files, differ


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    files, differ = differing(sys.argv[1], sys.argv[2])
    print(f"{len(files)} files " + ("identical" if not differ else "DIFFER: " + " ".join(differ)))
    sys.exit(1 if differ else 0)
