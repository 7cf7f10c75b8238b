#!/usr/bin/env bash
# Runs every fuzz target (fuzz/fuzz_targets, cargo-fuzz, libFuzzer) for a bounded time, and fails
# on the first crash, timeout or out-of-memory:
#   scripts/fuzz.sh [SECONDS_PER_TARGET] [TARGET...]      (default: 15 s, every target)
#   FUZZ_JOBS=1 scripts/fuzz.sh ...                       (one target at a time; default 2)
#   scripts/fuzz.sh --build-only                          (the tools and the build, no run)
# Installs what it needs: the nightly toolchain (rustup, minimal profile) and cargo-fuzz (`cargo
# install --locked`, once). Each target starts from its committed corpus (fuzz/corpus/<target>),
# which it only reads: new inputs go to a scratch copy in target/fuzz-corpus/<target>, so a short
# run never grows the repository. A crash's reproducer lands in fuzz/artifacts/<target>/, where the
# corpus replay (`cargo test -p pab-fuzz-checks`) keeps running it; commit it with the fix.
# Prints one line per target: executions, libFuzzer's coverage (cov: edges, ft: features), time.
set -euo pipefail
cd "$(dirname "$0")/.."

build_only=false
if [ "${1:-}" = "--build-only" ]; then
    build_only=true
    shift
fi
seconds="${1:-15}"
shift || true

rustup toolchain install nightly --profile minimal
if ! cargo +nightly fuzz --version > /dev/null 2>&1; then
    cargo install cargo-fuzz --locked
fi
cargo +nightly fuzz --version

# One build of every target (the sanitizer's instrumented dependencies are shared). After a
# --build-only run with the same CARGO_TARGET_DIR, it has nothing left to do.
cargo +nightly fuzz build
if "$build_only"; then
    exit 0
fi

targets=("$@")
if [ ${#targets[@]} -eq 0 ]; then
    mapfile -t targets < <(cargo +nightly fuzz list)
fi
target_dir="${CARGO_TARGET_DIR:-target}"
# Two targets at a time (libFuzzer runs one process on one core; the machines this runs on have
# two): the wall time halves, each target still gets its full SECONDS.
jobs="${FUZZ_JOBS:-2}"

# run_target NAME: one bounded run; its summary line in target/fuzz-corpus/NAME.line.
run_target() {
    local name="$1"
    local scratch="$target_dir/fuzz-corpus/$name"
    local log="$target_dir/fuzz-corpus/$name.log"
    rm -rf "$scratch" "$target_dir/fuzz-corpus/$name.line"
    mkdir -p "$scratch"
    # -timeout: an input that takes 20 s is a hang; -rss_limit_mb: libFuzzer's default.
    if ! cargo +nightly fuzz run "$name" "$scratch" "fuzz/corpus/$name" -- \
        -max_total_time="$seconds" -timeout=20 -rss_limit_mb=2048 -print_final_stats=1 \
        > "$log" 2>&1; then
        tail -n 60 "$log" >&2
        echo "fuzz: $name failed (log: $log; reproducer in fuzz/artifacts/$name/)" >&2
        return 1
    fi
    # libFuzzer's last status line (#N DONE cov: .. ft: .. corp: ..) and its run count.
    local status runs
    status=$(grep -E '^#[0-9]+[[:space:]]+DONE' "$log" | tail -n 1 || true)
    runs=$(grep -E '^stat::number_of_executed_units:' "$log" | awk '{print $2}' || true)
    local line="$name: ${runs:-?} executions in ${seconds} s; ${status:-no final status}"
    echo "fuzz: $line"
    echo "$line" > "$target_dir/fuzz-corpus/$name.line"
}

mkdir -p "$target_dir/fuzz-corpus"
running=0
failed=0
for name in "${targets[@]}"; do
    if [ "$running" -ge "$jobs" ]; then
        wait -n || failed=1
        running=$((running - 1))
    fi
    [ "$failed" -eq 0 ] || break
    run_target "$name" &
    running=$((running + 1))
done
while [ "$running" -gt 0 ]; do
    wait -n || failed=1
    running=$((running - 1))
done
if [ "$failed" -ne 0 ]; then
    echo "fuzz: a target failed (above)" >&2
    exit 1
fi
printf '\nfuzz summary (%s s per target, %s at a time):\n' "$seconds" "$jobs"
for name in "${targets[@]}"; do
    printf '  %s\n' "$(cat "$target_dir/fuzz-corpus/$name.line")"
done
