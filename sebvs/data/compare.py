"""``sebvs data compare A B``: are two datasets the same recording?

Lockstep recordings are reproducible: the same topology, seed and episode numbers give the
same episodes whatever the worker count, placement or machine load (docs/scale.md). What
legitimately differs between two such recordings is not the episode's:

- ``latency/*``: hop latencies measured on the wall clock;
- ``tick`` and ``t_sim``: they count from the start of the run that recorded the episode
  (a worker's run starts at its first episode), so they are compared from the episode's
  first frame (t_sim to a nanosecond);
- the index's sha256 and byte sizes, which follow from the above.

Everything else, every array and every file attribute, must be equal. Episodes are paired
by file name (index order); an episode on one side only is a difference too.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from .index import DatasetIndex

MEASURED_PREFIX = "latency/"
RUN_RELATIVE = ("tick", "t_sim")
RUN_RELATIVE_ATOL_S = 1e-9


def dataset_names(h5: h5py.File) -> list[str]:
    """Every dataset's path in an HDF5 file, sorted."""
    names: list[str] = []
    h5.visititems(lambda name, obj: names.append(name) if isinstance(obj, h5py.Dataset)
                  else None)
    return sorted(names)


def episode_differences(a: Path, b: Path) -> list[str]:
    """What differs between two episode files, beyond what is not the episode's (module
    docstring); empty when they are the same episode. One line per difference."""
    out: list[str] = []
    with h5py.File(a, "r") as fa, h5py.File(b, "r") as fb:
        na, nb = dataset_names(fa), dataset_names(fb)
        for name in sorted(set(na) ^ set(nb)):
            out.append(f"dataset {name}: only in {a if name in na else b}")
        for name in sorted(set(na) & set(nb)):
            if name.startswith(MEASURED_PREFIX):
                continue
            va, vb = fa[name][()], fb[name][()]
            if va.shape != vb.shape or va.dtype != vb.dtype:
                out.append(f"dataset {name}: {va.dtype}{list(va.shape)} against "
                           f"{vb.dtype}{list(vb.shape)}")
                continue
            if name in RUN_RELATIVE and va.size:
                va, vb = va - va[0], vb - vb[0]
            if name in RUN_RELATIVE and va.dtype.kind == "f":
                # a difference of sums (t0 + t) - t0 rounds: equal to a nanosecond
                unequal = ~np.isclose(va, vb, rtol=0.0, atol=RUN_RELATIVE_ATOL_S)
            else:
                unequal = va != vb
            if va.dtype.kind == "f":
                unequal &= ~(np.isnan(va) & np.isnan(vb))
            if not np.any(unequal):
                continue
            if va.ndim == 0:
                out.append(f"dataset {name}: {va!r} against {vb!r}")
            else:
                bad = np.argwhere(unequal)
                out.append(f"dataset {name}: {len(bad)} element(s) differ, first at "
                           f"{tuple(int(i) for i in bad[0])}")
        ka, kb = set(fa.attrs), set(fb.attrs)
        for key in sorted(ka ^ kb):
            out.append(f"attribute {key}: only in {a if key in ka else b}")
        for key in sorted(ka & kb):
            if str(fa.attrs[key]) != str(fb.attrs[key]):
                out.append(f"attribute {key}: {str(fa.attrs[key])[:60]!r} against "
                           f"{str(fb.attrs[key])[:60]!r}")
    return out


@dataclass
class Comparison:
    a: Path
    b: Path
    same: list[str] = field(default_factory=list)              # episode files
    different: dict[str, list[str]] = field(default_factory=dict)
    only_a: list[str] = field(default_factory=list)
    only_b: list[str] = field(default_factory=list)

    @property
    def identical(self) -> bool:
        return not (self.different or self.only_a or self.only_b)


def compare_datasets(a: Path, b: Path, progress=lambda name: None) -> Comparison:
    """Pair the indexed episodes of two datasets by file name and compare each pair."""
    files_a = [e["file"] for e in DatasetIndex(a).episodes()]
    files_b = [e["file"] for e in DatasetIndex(b).episodes()]
    in_a, in_b = set(files_a), set(files_b)
    result = Comparison(Path(a), Path(b))
    result.only_a = [f for f in files_a if f not in in_b]
    result.only_b = [f for f in files_b if f not in in_a]
    for name in (f for f in files_a if f in in_b):
        diffs = episode_differences(Path(a) / name, Path(b) / name)
        if diffs:
            result.different[name] = diffs
        else:
            result.same.append(name)
        progress(name)
    return result


def cmd_compare(args) -> int:
    from tqdm import tqdm
    for d in (args.a, args.b):
        if not (Path(d) / "index.json").is_file():
            print(f"sebvs data compare: {d} is not a dataset (no index.json)")
            return 2
    total = len(DatasetIndex(Path(args.a)).episodes())
    with tqdm(total=total, unit="episode", desc="compare", disable=args.quiet) as bar:
        result = compare_datasets(Path(args.a), Path(args.b), lambda name: bar.update())
    for name in result.only_a:
        print(f"{name}: only in {args.a}")
    for name in result.only_b:
        print(f"{name}: only in {args.b}")
    for name, diffs in result.different.items():
        for line in diffs[:args.max_lines]:
            print(f"{name}: {line}")
        if len(diffs) > args.max_lines:
            print(f"{name}: ... and {len(diffs) - args.max_lines} more")
    n = len(result.same) + len(result.different)
    print(f"{n} episode pair(s) compared: {len(result.same)} the same, "
          f"{len(result.different)} different; {len(result.only_a)} only in {args.a}, "
          f"{len(result.only_b)} only in {args.b} (hop latencies not compared; tick and "
          f"t_sim from each episode's first frame)")
    return 0 if result.identical else 1
