"""The size of the proof's tree, level by level: the phase of the certificate's branch and bound that
proves c > 0, run breadth first. Every box of the r faces whose bound (certificate.Ratio.boxes, the
parent's bound kept when smaller) is >= 0 is split in two along the coordinate the split rule
chooses; printed per depth: the boxes evaluated, those still open, and the CPU seconds so far. The
witness search, the retiring and the memory caps of certificate._maximise are left out, so two
versions of the bound (or two k) compare on the same work: e.g. r = 6 with the 6-decade gains at
k = 0 (the tree closes at depth 36, 1.1e6 boxes) and at k = -0.002.

    python -m benchmarks certificate_tree [--r 6] [--k -0.002] [--gains 0.62,1.15,1.54,3.88,39.13,1e5] [--depth 20] [--where]

--where: after the last depth, where the open boxes are, per face: the share that touches s_i = 0
(an end at 0), the median width and the split rule's choices, per coordinate s_i (the boxes that
keep the proof open: wide ones, or thin ones at a zero).

Deterministic; one core; r = 6, k = -0.002, --depth 20: about 15 s.
"""

import argparse
import time

import numpy as np

from ftstab_mj.control.certificate import Ratio
from ftstab_mj.control.hong_terms import Terms

CHUNK = 65536  # boxes evaluated at once (memory)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--r", type=int, default=6)
    ap.add_argument("--k", type=float, default=-0.002)
    ap.add_argument("--gains", default="0.62,1.15,1.54,3.88,39.13,1e5")
    ap.add_argument("--depth", type=int, default=20)
    ap.add_argument("--max-open", type=int, default=2_000_000, help="stop when more boxes than this are open")
    ap.add_argument("--where", action="store_true", help="where the open boxes of the last depth are")
    args = ap.parse_args(argv)
    r, d = args.r, args.r - 1
    obj = Ratio(Terms(r, args.k, tuple(float(g) for g in args.gains.split(","))), "c")
    lo, hi, face = np.full((r, d), -1.0), np.full((r, d), 1.0), np.arange(r)
    parent = np.full(r, np.inf)
    t0, total = time.process_time(), 0
    print("| depth | boxes | open | CPU s |")
    print("|---|---|---|---|")
    for depth in range(args.depth):
        ub, split = np.empty(len(lo)), np.empty(len(lo), dtype=int)
        for f in range(r):
            idx = np.nonzero(face == f)[0]
            for c in range(0, len(idx), CHUNK):
                sel = idx[c:c + CHUNK]
                ub[sel], split[sel] = obj.boxes(f, lo[sel], hi[sel])[:2]
        ub = np.minimum(ub, parent)  # a child lies in its parent
        total += len(lo)
        keep = ub >= 0
        print(f"| {depth} | {len(lo)} | {int(keep.sum())} | {time.process_time() - t0:.1f} |", flush=True)
        lo, hi, face, ub, split = lo[keep], hi[keep], face[keep], ub[keep], split[keep]
        if args.where and (depth == args.depth - 1 or not len(lo) or len(lo) > args.max_open):
            where(r, lo, hi, face, split)
        if not len(lo) or len(lo) > args.max_open:
            break
        rows = np.arange(len(lo))
        cut = 0.5 * (lo[rows, split] + hi[rows, split])
        hi1, lo2 = hi.copy(), lo.copy()
        hi1[rows, split] = cut
        lo2[rows, split] = cut
        lo, hi, face, parent = (np.concatenate([lo, lo2]), np.concatenate([hi1, hi]), np.concatenate([face, face]),
                                np.concatenate([ub, ub]))
    print(f"boxes evaluated: {total}; {'closed' if not len(lo) else f'{len(lo)} children of open boxes not evaluated'}")


def where(r, lo, hi, face, split):
    """Per face and coordinate s_i of the open boxes: share touching s_i = 0, median width, splits."""
    print("| face | open | s_i: touches 0, median width, split share |")
    print("|---|---|---|")
    for f in range(r):
        sel = face == f
        if not sel.any():
            continue
        cells = []
        for j, i in enumerate(i for i in range(r) if i != f):
            touch = np.mean((lo[sel, j] <= 0) & (hi[sel, j] >= 0))
            cells.append(f"s_{i + 1}: {touch:.0%}, {np.median(hi[sel, j] - lo[sel, j]):.3g}, {np.mean(split[sel] == j):.0%}")
        print(f"| s_{f + 1} = 1 | {int(sel.sum())} | {'; '.join(cells)} |")


if __name__ == "__main__":
    main()
