#!/usr/bin/env python3
"""A flat W x 0.6 W sheet meshed by a Delaunay triangulation of scattered points, as an OFF file
for `nonrigid_register sheets --target-mesh` (a meshing our generator does not make).

    sheet_delaunay.py WIDTH INNER EDGE SEED OUT.off

INNER points inside the sheet, kept at least 0.6 of their mean spacing apart; EDGE points at
random along each long side and 0.6 x EDGE along each short one, besides the four corners.
Needs numpy and scipy (the peers' venv has both).
"""
import sys

import numpy as np
from scipy.spatial import Delaunay


def main():
    width, inner_count, edge_count, seed = (
        float(sys.argv[1]),
        int(sys.argv[2]),
        int(sys.argv[3]),
        int(sys.argv[4]),
    )
    out = sys.argv[5]
    rng = np.random.default_rng(seed)
    w, h = width / 2, 0.3 * width
    corners = [(-w, -h), (w, -h), (w, h), (-w, h)]
    points = list(corners)
    for k in range(4):
        (ax, ay), (bx, by) = corners[k], corners[(k + 1) % 4]
        count = edge_count if k % 2 == 0 else int(0.6 * edge_count)
        for t in np.sort(rng.uniform(0.03, 0.97, count)):
            points.append((ax + (bx - ax) * t, ay + (by - ay) * t))
    gap = 0.6 * np.sqrt(width * 0.6 * width / inner_count)
    inner = []
    while len(inner) < inner_count:
        p = (rng.uniform(-w + 0.3 * gap, w - 0.3 * gap), rng.uniform(-h + 0.3 * gap, h - 0.3 * gap))
        if all((p[0] - q[0]) ** 2 + (p[1] - q[1]) ** 2 > gap * gap for q in inner):
            inner.append(p)
    points = np.array(points + inner)
    triangles = Delaunay(points).simplices
    with open(out, "w") as f:
        f.write("OFF\n%d %d 0\n" % (len(points), len(triangles)))
        for x, y in points:
            f.write("%.9f %.9f 0\n" % (x, y))
        for a, b, c in triangles:
            ab, ac = points[b] - points[a], points[c] - points[a]
            if ab[0] * ac[1] - ab[1] * ac[0] < 0:
                b, c = c, b  # counter-clockwise: normals +z
            f.write("3 %d %d %d\n" % (a, b, c))


if __name__ == "__main__":
    main()
