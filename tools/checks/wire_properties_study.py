#!/usr/bin/env python3
"""The long run of tests/test_wire_properties.py: every property of the wire decoder, the
array descriptors and the control values with --examples examples each (100,000 by
default; CI runs 1,500). Prints per property whether it held and how long it took, as JSON.

    tools/checks/wire_properties_study.py [--examples N] [--json FILE]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PROPERTIES = ("test_any_bytes_decode_or_raise_wire_error",
              "test_header_like_maps_decode_valid_or_raise_wire_error",
              "test_what_encode_header_writes_decodes_to_the_same",
              "test_array_descriptors_give_a_bounded_array_or_raise_wire_error",
              "test_control_sets_a_valid_value_or_refuses_and_keeps_the_old")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--examples", type=int, default=100_000)
    ap.add_argument("--json", metavar="FILE")
    args = ap.parse_args()
    env = dict(os.environ, SEBVS_PROPERTY_EXAMPLES=str(args.examples))
    rows = []
    for name in PROPERTIES:
        t0 = time.monotonic()
        done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                               "-o", "addopts=", "--timeout=0",
                               f"tests/test_wire_properties.py::{name}"],
                              cwd=ROOT, env=env, capture_output=True, text=True)
        rows.append({"property": name, "examples": args.examples,
                     "held": done.returncode == 0, "seconds": round(time.monotonic() - t0, 1),
                     "output": done.stdout[-2000:] if done.returncode else ""})
        print(f"{name}: {'held' if done.returncode == 0 else 'FAILED'} "
              f"({rows[-1]['seconds']} s)", flush=True)
    out = {"examples": args.examples, "properties": rows,
           "all_held": all(r["held"] for r in rows)}
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0 if out["all_held"] else 1


if __name__ == "__main__":
    sys.exit(main())
