#!/usr/bin/env bash
# Runs the deterministic cases with two builds and says, per case, whether their results are the
# same (the JSON lines without timings, thread counts and paths; the grid table without its
# seconds): pose graphs with three algorithms, bundle adjustment with three Schur solvers, the camel
# and DeepDeform registrations, the thesis' grid, the default non-rigid and rigid runs (trajectory
# and mesh files byte for byte).
#
# usage: bash bench/same_results.sh OLD_BIN_DIR NEW_BIN_DIR OUT_DIR
# Each BIN_DIR holds pose_graph, bundle_adjustment, nonrigid_register, nonrigid_slam and rigid_slam
# (e.g. target/release of two worktrees). nonrigid_register is called with its subcommands (grid,
# meshes, frames); for binaries older than them, put a wrapper in BIN_DIR that drops the first word.
set -u
old=$1
new=$2
out=$3
mkdir -p "$out"
data="$(cd "$(dirname "$0")/../.." && pwd)/shared/data"
strip() {
  python3 -c '
import json, sys
for line in sys.stdin:
    try:
        d = json.loads(line)
    except ValueError:
        continue
    if isinstance(d, dict):
        for k in ["seconds", "init_seconds", "threads", "fps", "ms_per_frame", "preprocess",
                  "optimise", "fuse", "surface", "optimise_ms", "sequence"]:
            d.pop(k, None)
        print(json.dumps(d, sort_keys=True))
'
}
same() {
  if [ -s "$out/$1.new" ] && cmp -s "$out/$1.old" "$out/$1.new"; then echo "same  $1"; else echo "DIFF  $1"; fi
}
run() {
  name=$1
  shift
  "$old/$@" -q 2>/dev/null | strip > "$out/$name.old"
  "$new/$@" -q 2>/dev/null | strip > "$out/$name.new"
  same "$name"
}
for g in intel sphere2500 torus3D parking-garage M3500; do
  for a in lm gn dogleg; do
    run "pg-$g-$a" pose_graph "$data/posegraph/$g.g2o" --algorithm $a --init chordal
  done
done
for s in schur-dense schur-sparse schur-iterative; do
  run "ba-$s" bundle_adjustment "$data/bal/problem-49-7776-pre.txt" --linear-solver $s
done
c=$data/nonrigid/camel_gallop
run camel-1-3 nonrigid_register meshes "$c/camel-gallop-01.off" "$c/camel-gallop-03.off" \
  --ground-truth "$c/maps/1_to_3"
d=$data/nonrigid/deepdeform_2pairs/train/seq258
run deepdeform-258 nonrigid_register frames "$d/depth/000000.png" "$d/depth/000110.png" \
  --intrinsics 575.548 577.46 323.172 236.417 --depth-scale 1000 --mask "$d/mask/000000_shirt.png" \
  --color "$d/color/000000.jpg" --target-color "$d/color/000110.jpg" \
  --flow-ground-truth "$d/scene_flow/shirt_000000_000110.sflow"
run nonrigid-default nonrigid_slam
for side in old new; do
  bin=$([ $side = old ] && echo "$old" || echo "$new")
  "$bin/nonrigid_register" grid -q | awk '{$NF=""; print}' > "$out/grid.$side"
  "$bin/rigid_slam" -q --output "$out/rigid-trajectory.$side" --mesh "$out/rigid-mesh.$side" > /dev/null
done
same grid
same rigid-trajectory
same rigid-mesh
