#!/usr/bin/python3
"""How many neighbour-loop trips an 8-lane SIMD batch runs in the masked PBF passes, by model
(docs/PERFORMANCE.md "PBF / Session 19").

Usage: /usr/bin/python3 tools/simd_trips_model.py [--jitter F] [--scale F] [--seed N]

The block scene's liquid (n x 0.8n x n particles at spacing d, cells of h0 = 2d, 2 x slices) as a
lattice moved by up to F d per axis at random and squeezed by a factor S (a disordered, slightly
compressed liquid), sorted by cell and slice as the grid build sorts it. For every particle it
counts, as shaders/pbf.wgsl does:
- its candidates: the particles of the 9 cell rows around its anchor, clipped to the slices
  `anchor_row` keeps for its 1/16-cell sub-cell (the mask has 175 bits; candidates past them
  are tested in every pass);
- its neighbours (closer than h0) per row.
A masked pass walks the rows one after the other and pops two neighbours per trip, so a batch of
8 consecutive particles runs, per row, as many trips as its busiest lane there. The model prints
that sum over the rows against the trips of one loop over a lane's whole mask (the busiest lane's
total), and the batches in which some lane has candidates past the mask.
"""
import argparse
from collections import defaultdict

import numpy as np

SUB = 16
MASK_BITS = 175
LANES = 8


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jitter", type=float, default=0.35, help="largest move per axis, in d")
    ap.add_argument("--scale", type=float, default=1.0, help="lattice spacing, in d")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--n", type=int, default=40, help="particles along x")
    a = ap.parse_args()

    d, h0, xs = 0.05, 0.1, 2
    rng = np.random.default_rng(a.seed)
    shape = (a.n, int(0.8 * a.n), a.n)
    lattice = np.stack(np.meshgrid(*[np.arange(k) for k in shape], indexing="ij"), -1).reshape(-1, 3)
    p = lattice * d * a.scale + 2 * d + rng.uniform(-a.jitter, a.jitter, lattice.shape) * d
    cell = np.floor(p / h0).astype(int)
    sl = np.floor(p[:, 0] / (h0 / xs)).astype(int)
    dims = cell.max(0) + 2
    key = ((cell[:, 2] * dims[1] + cell[:, 1]) * dims[0]) * xs + sl
    order = np.argsort(key, kind="stable")
    p, cell, sl = p[order], cell[order], sl[order]
    sub = np.clip(np.floor((p - cell * h0) / h0 * SUB).astype(int), 0, SUB - 1)

    rows = defaultdict(list)
    for i in range(len(p)):
        rows[(cell[i, 1], cell[i, 2])].append(i)
    rows = {k: np.array(v) for k, v in rows.items()}

    n = len(p)
    cand = np.zeros(n, int)
    nbr = np.zeros((n, 9), int)
    for i in range(n):
        s = sub[i]
        for k, (dz, dy) in enumerate((z, y) for z in (-1, 0, 1) for y in (-1, 0, 1)):
            members = rows.get((cell[i, 1] + dy, cell[i, 2] + dz))
            if members is None:
                continue
            # anchor_row: the slices within SUB units of the sub-cell
            gy = max(dy * SUB - (s[1] + 1), s[1] - (dy + 1) * SUB, 0)
            gz = max(dz * SUB - (s[2] + 1), s[2] - (dz + 1) * SUB, 0)
            rem = SUB * SUB - gy * gy - gz * gz
            if rem <= 0:
                continue
            r = int(np.sqrt(rem - 1))
            sx = s[0] + SUB
            lo = max(((sx - r + 7) >> 3) - 1, 0)
            hi = min((sx + 1 + r) >> 3, 3 * xs - 1)
            x0 = (cell[i, 0] - 1) * xs
            in_row = members[(sl[members] >= x0 + lo) & (sl[members] <= x0 + hi)]
            cand[i] += len(in_row)
            q = p[in_row] - p[i]
            nbr[i, k] = ((q * q).sum(1) < h0 * h0).sum()

    batches = n // LANES
    trips = ((nbr + 1) // 2)[: batches * LANES].reshape(batches, LANES, 9)
    per_row = trips.max(1).sum(1)
    whole = ((nbr.sum(1) + 1) // 2)[: batches * LANES].reshape(batches, LANES).max(1)
    over = (cand[: batches * LANES].reshape(batches, LANES) > MASK_BITS).any(1)
    print(f"particles {n}, jitter {a.jitter} d, spacing {a.scale} d")
    print(f"per particle: candidates {cand.mean():.1f} (99th percentile {np.percentile(cand, 99):.0f}),"
          f" neighbours {nbr.sum(1).mean():.1f}, rows holding one {(nbr > 0).sum(1).mean():.1f}")
    print(f"trips per batch: row by row {per_row.mean():.1f}, one loop over the mask {whole.mean():.1f},"
          f" a lane's mean {nbr.sum(1).mean() / 2:.1f}")
    print(f"past the mask's {MASK_BITS} bits: {100 * (cand > MASK_BITS).mean():.1f}% of particles,"
          f" {100 * over.mean():.1f}% of batches")


if __name__ == "__main__":
    main()
