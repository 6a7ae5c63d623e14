#!/usr/bin/env bash
# Runs every fuzz target for SECONDS each (default 600), one after another, then minimises each
# corpus in place. Findings land in artifacts/<target>/; the log of each run in $LOGS (default
# /tmp/dynamap-fuzz). Needs the nightly toolchain and cargo-fuzz (`cargo install cargo-fuzz`).
set -euo pipefail
cd "$(dirname "$0")"
SECONDS_EACH=${1:-600}
LOGS=${LOGS:-/tmp/dynamap-fuzz}
TARGETS=(${TARGETS:-g2o bal tum mesh intrinsics config})
mkdir -p "$LOGS"
cargo +nightly fuzz build
BIN=target/x86_64-unknown-linux-gnu/release
for t in "${TARGETS[@]}"; do
    mkdir -p "corpus/$t" "artifacts/$t"
    echo "== $t: ${SECONDS_EACH}s, log in $LOGS/$t.log"
    "$BIN/$t" "corpus/$t" -max_total_time="$SECONDS_EACH" -max_len=16384 -timeout=10 \
        -artifact_prefix="artifacts/$t/" -print_final_stats=1 >"$LOGS/$t.log" 2>&1 \
        || echo "   $t stopped with a finding: see $LOGS/$t.log and artifacts/$t/"
    tail -n 20 "$LOGS/$t.log" | grep -E "^(#[0-9]+ +DONE|stat::number_of_executed_units|Done)" || true
done
for t in "${TARGETS[@]}"; do
    cargo +nightly fuzz cmin "$t" "corpus/$t" >/dev/null 2>&1 || echo "   cmin of $t failed"
done
