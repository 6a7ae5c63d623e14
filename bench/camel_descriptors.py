#!/usr/bin/env python3
"""Diagnostic for issue 5 point 2: do geodesic descriptors keep the camel's legs on their side?

usage (numpy and scipy, e.g. the peers' venv):
  ~/.cache/dynamap-peers/bin/python bench/camel_descriptors.py I J WARPED.ply [--anchors 16] [--core 15]
      [--map MAP]

I, J: camel poses (map I_to_J of ../shared/data/nonrigid/camel_gallop); WARPED.ply: the output of
`nonrigid_register meshes camel-gallop-0I.off camel-gallop-0J.off --seeded-passes 0 --output WARPED.ply`
(the one-pass registration, whose result places the anchors, as in `register_meshes`). MAP: a
ground-truth map other than the data's maps/I_to_J (e.g. a chained one from camel_heldout.py).

Anchors: farthest-point samples over the source's most central CORE % of vertices. Each anchor's
partner is the target vertex closest to its warped position. Every vertex is described by its
shortest-path distances along the mesh edges to the anchors, and matched to the target vertex with
the nearest description. Prints, for the leg vertices (source height below 0.25) and over all scored
vertices, how often the match lies on the other side of the body than the ground-truth partner
(the sign of x, the camel's lateral axis, differs) and the mean error in % of the diagonal, beside
the same for closest point from the warped position.
"""
import argparse, os
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "data", "nonrigid", "camel_gallop")


def read_off(path):
    lines = open(path).read().split("\n")
    n, f, _ = map(int, lines[1].split())
    v = np.array([list(map(float, l.split()[:3])) for l in lines[2:2 + n]])
    faces = np.array([list(map(int, l.split()[1:4])) for l in lines[2 + n:2 + n + f]])
    return v, faces


def read_ply_vertices(path, n):
    data = open(path, "rb").read()
    start = data.index(b"end_header\n") + len(b"end_header\n")
    return np.frombuffer(data[start:start + n * 24], dtype="<f4").reshape(-1, 6)[:, :3].astype(float)


def edge_graph(v, faces):
    e = np.vstack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    w = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
    n = len(v)
    return coo_matrix((np.r_[w, w], (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("i", type=int)
    ap.add_argument("j", type=int)
    ap.add_argument("warped")
    ap.add_argument("--anchors", type=int, default=16)
    ap.add_argument("--core", type=float, default=15.0)
    ap.add_argument("--map", help="ground-truth map (default: the data's maps/I_to_J)")
    a = ap.parse_args()
    s, sf = read_off(os.path.join(DATA, f"camel-gallop-{a.i:02d}.off"))
    t, tf = read_off(os.path.join(DATA, f"camel-gallop-{a.j:02d}.off"))
    w = read_ply_vertices(a.warped, len(s))
    partner = np.array([int(x) for x in open(a.map or os.path.join(DATA, "maps", f"{a.i}_to_{a.j}")).read().split()])
    scored = partner != np.argmax(np.bincount(partner, minlength=len(t)))  # the placeholder vertex
    diag = np.linalg.norm(t.max(0) - t.min(0))
    legs = scored & (s[:, 1] < 0.25)

    centre_distance = np.linalg.norm(s - s.mean(0), axis=1)
    core = np.where(centre_distance < np.percentile(centre_distance, a.core))[0]
    anchors = [core[np.argmax(s[core, 0])]]
    d = np.linalg.norm(s[core] - s[anchors[0]], axis=1)
    for _ in range(a.anchors - 1):
        k = core[np.argmax(d)]
        anchors.append(k)
        d = np.minimum(d, np.linalg.norm(s[core] - s[k], axis=1))
    target_tree = cKDTree(t)
    anchor_partners = target_tree.query(w[anchors])[1]
    ds = dijkstra(edge_graph(s, sf), indices=anchors).T
    dt = dijkstra(edge_graph(t, tf), indices=anchor_partners).T
    by_descriptor = cKDTree(dt).query(ds)[1]
    by_closest = target_tree.query(w)[1]
    for name, match in (("closest point", by_closest), ("descriptor", by_descriptor)):
        flip = np.sign(t[match, 0]) != np.sign(t[partner, 0])
        err = np.linalg.norm(t[match] - t[partner], axis=1) / diag
        print(f"{name:13s}: legs across the body {100 * flip[legs].mean():5.1f} %, leg error "
              f"{100 * err[legs].mean():5.2f} %, all scored {100 * err[scored].mean():5.2f} %")


if __name__ == "__main__":
    main()
