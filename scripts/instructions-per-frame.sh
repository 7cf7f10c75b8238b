#!/usr/bin/env bash
# Instructions per `Arbiter::receive` call, counted by callgrind (repeatable: it counts, it does
# not time). Each case runs with 10 000 and 20 000 frames; the difference divided by 10 000 is the
# cost of one frame, setup excluded. Needs valgrind (apt-get install valgrind).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build -q --release -p pab-core --example receive_loop
binary=target/release/examples/receive_loop
count() {
    valgrind --tool=callgrind --callgrind-out-file=/dev/null "$binary" "$1" "$2" 2>&1 \
        | sed -n 's/.*Collected : \([0-9]*\).*/\1/p'
}
printf '%-10s %s\n' case instructions/frame
for case in walk-4 walk-16 walk-32 active-4 active-16 active-32 full; do
    low=$(count "$case" 10000)
    high=$(count "$case" 20000)
    printf '%-10s %s\n' "$case" $(( (high - low) / 10000 ))
done
