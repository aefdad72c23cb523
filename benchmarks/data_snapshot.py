"""Data snapshot: what the procedural generator gives, saved once and compared bit for bit later.

A refactor of the family modules (moving a family, sharing a helper, splitting a file) must change nothing the
dataset holds. Before it, save; after it, compare:

    python -m benchmarks.data_snapshot save    /tmp/data_before.npz
    python -m benchmarks.data_snapshot compare /tmp/data_before.npz     # exit 1 on any difference

What it covers (~10 s): the registry's family order, the caption lexicon, and for every family 3 clips (joints,
captions, segments with their parameters), 4 long sequences and 4 path sequences, each from fixed seeds. A change
that is meant to change the data (a new family appended, a fixed motion) shows up here as exactly what it touched.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from .snapshot import save_or_compare

SEEDS = (0, 1, 2)
SEQUENCE_SEEDS = (0, 1, 2, 3)


def _clip_arrays(name: str, clip) -> dict[str, np.ndarray]:
    meta = {"captions": clip.captions, "segments": [[s.family, int(s.start), int(s.end), repr(s.params)]
                                                    for s in clip.segments]}
    return {f"{name}/joints": np.asarray(clip.joints),
            f"{name}/meta": np.frombuffer(json.dumps(meta, sort_keys=True).encode(), np.uint8)}


def snapshot() -> dict[str, np.ndarray]:
    from mogo_export.data.procedural import captions
    from mogo_export.data.procedural.clips import generate_clip
    from mogo_export.data.procedural.families import FAMILIES
    from mogo_export.data.procedural.paths import generate_path_sequence
    from mogo_export.data.procedural.sequences import generate_long

    out = {"registry": np.frombuffer(json.dumps(list(FAMILIES)).encode(), np.uint8),
           "lexicon": np.frombuffer(json.dumps(captions.lexicon(), sort_keys=True).encode(), np.uint8)}
    for family in FAMILIES:
        for seed in SEEDS:
            out.update(_clip_arrays(f"clip/{family}/{seed}", generate_clip((family,), np.random.default_rng(seed))))
    for seed in SEQUENCE_SEEDS:
        out.update(_clip_arrays(f"long/{seed}", generate_long(np.random.default_rng(seed))))
        out.update(_clip_arrays(f"path/{seed}", generate_path_sequence(np.random.default_rng(seed))))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=["save", "compare"])
    ap.add_argument("file")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    return save_or_compare(args.mode, args.file, snapshot(), t0)


if __name__ == "__main__":
    sys.exit(main())
