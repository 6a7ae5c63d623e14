#!/usr/bin/env python3
"""Time and peak memory against problem size, log-log, one line per system, with the fitted slope of
each line (the exponent k of time ~ size^k, least squares on the logarithms).

usage: bench/scaling.py [--posegraph JSON...] [--bal JSON...] [--out DIR] [--title TEXT]

- --posegraph: files written by ../shared/bench/compare_posegraph.py --json. A graph's family is its
  file name without the size (city2-100k.g2o -> city2), its size the number of poses in the name
  (10k, 100k, 1m).
- --bal: files written by bench/compare_bal.py --json; the family is the file name without the
  camera count (streets-1000.txt -> streets), the size the camera count.
A system that timed out or was not run at a size has no point there; a line needs two points for a
slope. Writes DIR/scaling-<family>.png (time and memory side by side; matplotlib, which the peers'
virtual environment holds) and prints a Markdown table of the slopes.
"""
import argparse, collections, json, math, os, re

SIZE = re.compile(r"^(.*?)[-_](\d+)(k|m)?\.[a-z0-9]+$", re.IGNORECASE)


def family_and_size(name):
    """('city2', 100000) for 'city2-100k.g2o'; None when the name carries no size."""
    m = SIZE.match(os.path.basename(name))
    if not m:
        return None
    scale = {"k": 1_000, "m": 1_000_000, None: 1}[m.group(3) and m.group(3).lower()]
    return m.group(1), int(m.group(2)) * scale


def posegraph_points(path):
    """(family, system, size, seconds, MB) of every finished run in a compare_posegraph JSON."""
    for row in json.load(open(path)):
        fs = family_and_size(row["graph"])
        if fs is None:
            continue
        for system, sec in row.get("seconds", {}).items():
            mb = row.get("peak_rss_mb", {}).get(system, float("nan"))
            if sec is not None and math.isfinite(sec):
                yield fs[0], system, fs[1], sec, mb


def bal_points(path):
    """(family, configuration, cameras, seconds, MB) of every finished run in a compare_bal JSON."""
    for row in json.load(open(path)):
        fs = family_and_size(row["file"])
        if fs is None or row.get("seconds") is None:
            continue
        yield fs[0], row["configuration"], fs[1], row["seconds"], row.get("rss_mb", float("nan"))


def slope(points):
    """The least-squares slope of log y against log x, None with fewer than two sizes."""
    pts = [(math.log(x), math.log(y)) for x, y in points if y and math.isfinite(y) and y > 0]
    if len({x for x, _ in pts}) < 2:
        return None
    mx = sum(x for x, _ in pts) / len(pts)
    my = sum(y for _, y in pts) / len(pts)
    sxx = sum((x - mx) ** 2 for x, _ in pts)
    return sum((x - mx) * (y - my) for x, y in pts) / sxx


def plot(family, lines, out, unit):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, index, label in ((axes[0], 0, "seconds"), (axes[1], 1, "peak RSS (MB)")):
        for system, pts in sorted(lines.items()):
            pts = sorted(pts)
            xs = [p[0] for p in pts]
            ys = [p[1 + index] for p in pts]
            k = slope(list(zip(xs, ys)))
            tag = f"{system} (slope {k:.2f})" if k is not None else system
            ax.plot(xs, ys, marker="o", label=tag, linewidth=2.4 if system.startswith(("ours", "dynamap")) else 1.2)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(unit)
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(family)
    fig.tight_layout()
    path = os.path.join(out, f"scaling-{family}.png")
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--posegraph", nargs="*", default=[])
    ap.add_argument("--bal", nargs="*", default=[])
    ap.add_argument("--out", default="docs/images")
    ap.add_argument("--no-plot", action="store_true", help="print the slopes only")
    a = ap.parse_args()
    data = collections.defaultdict(lambda: collections.defaultdict(dict))
    units = {}
    for path in a.posegraph:
        for fam, system, size, sec, mb in posegraph_points(path):
            data[fam][system][size] = (sec, mb)
            units[fam] = "poses"
    for path in a.bal:
        for fam, system, size, sec, mb in bal_points(path):
            data[fam][system][size] = (sec, mb)
            units[fam] = "cameras"
    print("| family | system | sizes | time slope | memory slope |")
    print("|---|---|---|---|---|")
    for fam in sorted(data):
        lines = {s: [(n, sec, mb) for n, (sec, mb) in sorted(v.items())] for s, v in data[fam].items()}
        for system, pts in sorted(lines.items()):
            kt = slope([(n, sec) for n, sec, _ in pts])
            km = slope([(n, mb) for n, _, mb in pts])
            sizes = ", ".join(f"{n:,}" for n, _, _ in pts)
            fmt = lambda k: "–" if k is None else f"{k:.2f}"
            print(f"| {fam} | {system} | {sizes} | {fmt(kt)} | {fmt(km)} |")
        if not a.no_plot:
            os.makedirs(a.out, exist_ok=True)
            print(f"<!-- {plot(fam, lines, a.out, units[fam])} -->")


if __name__ == "__main__":
    main()
