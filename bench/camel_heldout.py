#!/usr/bin/env python3
"""Held-out check for issue 5 point 2: camel pairs that have no ground-truth map of their own.

usage (numpy):
  ~/.cache/dynamap-peers/bin/python bench/camel_heldout.py OUT_DIR [--check]

The 30 maps in ../shared/data/nonrigid/camel_gallop/maps were also the maps the seeding's
settings were chosen on. Two maps chained through a third pose, i -> k -> j, give a ground truth
for a pair (i, j) that has no map of its own: vertex v of mesh i goes to map_kj[map_ik[v]].
Entries that point at a placeholder (a vertex that over 1 % of the sources point at, "no partner",
as `nonrigid_register meshes --ground-truth` reads them; NOTES 20) in either map become placeholders of
the chain: they point at vertex 0 of mesh j. Writes every such composed map to OUT_DIR/i_to_j
(the format of the given maps, taking for each pair the intermediate pose k of smallest number)
and prints one line per pair.

--check measures what chaining costs: for every pair that has a map of its own and also a chain
through some k, the distance on mesh j between the direct partner and the chained partner, in %
of mesh j's bounding-box diagonal (mean and 95th percentile over the vertices scored in both,
per pair and over all of them).
"""
import argparse, os
import numpy as np

DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "data", "nonrigid", "camel_gallop")


def read_off_vertices(path):
    lines = open(path).read().split("\n")
    n = int(lines[1].split()[0])
    return np.array([list(map(float, l.split()[:3])) for l in lines[2:2 + n]])


def read_maps():
    maps = {}
    for name in os.listdir(os.path.join(DATA, "maps")):
        i, j = map(int, name.split("_to_"))
        maps[(i, j)] = np.array([int(x) for x in open(os.path.join(DATA, "maps", name)).read().split()])
    return maps


def scored(m):
    """False where an entry points at a placeholder: a vertex that over 1 % of the sources point at."""
    count = np.bincount(m)
    return count[m] * 100 <= len(m)


def compose(maps, i, k, j):
    """The chain i -> k -> j and where it is scored."""
    first, second = maps[(i, k)], maps[(k, j)]
    ok = scored(first) & scored(second)[first]
    return second[first], ok


def chains(maps, i, j):
    """The intermediate poses k with maps i -> k and k -> j, smallest first."""
    return sorted(k for (a, k) in maps if a == i and (k, j) in maps and k != j)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--check", action="store_true")
    a = ap.parse_args()
    maps = read_maps()
    poses = sorted({i for pair in maps for i in pair})
    if a.check:
        verts = {p: read_off_vertices(os.path.join(DATA, f"camel-gallop-{p:02d}.off")) for p in poses}
        every = []
        for (i, j), direct in sorted(maps.items()):
            for k in chains(maps, i, j):
                v = verts[j]
                diag = np.linalg.norm(v.max(0) - v.min(0))
                chained, ok = compose(maps, i, k, j)
                ok &= scored(direct)
                d = np.linalg.norm(v[direct[ok]] - v[chained[ok]], axis=1) / diag * 100
                every.append(d)
                print(f"{i}->{j} via {k}: mean {d.mean():.2f} %, p95 {np.percentile(d, 95):.2f} %")
        d = np.concatenate(every)
        print(f"all {len(every)} chains: mean {d.mean():.2f} %, p95 {np.percentile(d, 95):.2f} %")
        return
    os.makedirs(a.out, exist_ok=True)
    count = 0
    for i in poses:
        for j in poses:
            if i == j or (i, j) in maps:
                continue
            ks = chains(maps, i, j)
            if not ks:
                continue
            k = ks[0]
            composed, ok = compose(maps, i, k, j)
            composed = np.where(ok, composed, 0)
            tmp = os.path.join(a.out, f".{i}_to_{j}.tmp")
            with open(tmp, "w") as f:
                f.write("\n".join(map(str, composed)) + "\n")
            os.replace(tmp, os.path.join(a.out, f"{i}_to_{j}"))
            print(f"{i} {j} via {k}: {ok.mean() * 100:.1f} % scored")
            count += 1
    print(f"{count} composed maps in {a.out}")


if __name__ == "__main__":
    main()
