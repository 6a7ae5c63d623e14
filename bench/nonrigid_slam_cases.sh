#!/bin/bash
# Runs `nonrigid_slam` on generated deforming sequences, one line per set of flags, each case's
# mean / worst-frame tracking error in millimetres over every sample (the JSON line's error_mean,
# error_max_frame), then over the samples the camera sees (error_seen_mean, error_seen_max_frame)
# and the worst seen error of a frame reported tracked (error_seen_max_fused).
#
#   bench/nonrigid_slam_cases.sh "plane:bend:3 cylinder:twist:7" "--chroma-weight 0" "--chroma-weight 0.3"
#
# Cases are surface:field:seed. Environment: BIN (default target/release/nonrigid_slam), SENSOR
# (default kinect), FRAMES (default 100).
set -euo pipefail
BIN=${BIN:-target/release/nonrigid_slam}
CASES="$1"
shift
for flags in "$@"; do
  line="[$flags]"
  for c in $CASES; do
    IFS=: read -r surface field seed <<< "$c"
    # shellcheck disable=SC2086
    r=$("$BIN" --surface "$surface" --field "$field" --seed "$seed" --sensor "${SENSOR:-kinect}" \
        --max-frames "${FRAMES:-100}" --quiet $flags \
      | grep -o '"error_mean": [0-9.nul]*, "error_max_frame": [0-9.nul]*, "error_seen_mean": [0-9.nul]*, "error_seen_max_frame": [0-9.nul]*, "error_seen_max_fused": [0-9.nul]*' \
      | tr -d ',' \
      | awk 'function mm(x) { return x == "null" ? "null" : sprintf("%.1f", x * 1000) }
             {printf "%s/%s(seen %s/%s,fused %s)", mm($2), mm($4), mm($6), mm($8), mm($10)}')
    line="$line $surface-$field-$seed=${r:-failed}"
  done
  echo "$line"
done
