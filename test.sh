#!/usr/bin/env bash
# Runs every check and test of the project, from a fresh clone on a fresh machine:
#   ./test.sh
# It installs what it needs (the Cortex-M target, rustfmt, clippy, llvm-tools) with rustup, then
# checks formatting, lints and the documentation's links, builds the book (mdBook) and checks
# its links, builds the core, the NUCLEO-G474RE and NUCLEO-F446RE firmware and the emulated
# board's (and prints their flash and RAM sizes), the example firmware on a driver that is not
# embassy's (pab-own-driver, checked free of embassy), counts the Cortex-M4 instructions per frame on
# the emulated board and checks them against their goals (scripts/cortex-m4-cost.sh --check),
# runs all tests (unit, property, end-to-end, command line, the node application on an
# in-process bus, the replay of the fuzz corpus through the fuzz targets' checks), runs each
# benchmark once in test mode, runs every fuzz target for 15 s under libFuzzer (scripts/fuzz.sh:
# installs the nightly toolchain and cargo-fuzz; fails on any crash), runs every example through
# `pabctl check` and `pabctl sim` (plots and traces land in target/examples/), checks the DBC export
# with cantools (in a venv made by scripts/python-env.sh from requirements-dev.txt), runs the HIL
# harness's own unit tests (hil-sim/unit) and the schema server's Python client's tests
# (client/python/tests), the ISO-TP CAN FD golden frames written again by python can-isotp
# (scripts/isotp_fd_golden.py), the cross-runner test with the board firmware in QEMU
# (scripts/cross-runner.sh: simulator, node application and emulated Cortex-M4 must record
# identical verdicts), the emulated board's time check across its timer's wraps and its builtins
# check, the panic check of the board firmware (scripts/panic-check.sh, built with its panic
# locations), the emulated board's watchdog and stack-guard
# test (scripts/watchdog-test.sh: a hung loop, an overflowed stack), the emulated board's
# bootloader (scripts/boot-test.sh: updates swapped, reverted, refused) and a reset at each of its
# flash operations (scripts/boot-reset-test.sh: the swap's and the revert's), the keyed emulated board
# (scripts/keyed-board-test.sh), and the
# hardware-in-the-loop suite (hil-sim/run-hil: on vcan0, or in a micro-VM; PAB_HIL_ACCEL=
# auto|kvm|tcg picks its accelerator), whose fresh Take and Return log then goes through the
# cross-runner test too. The lints, the documentation build, the core without dynamics and the
# benchmarks run in the background from the start (at nice 19, in target/background: they take
# the time the other steps leave idle), the DBC export and the cross-runner test beside the HIL
# suite; the run waits for them after the suite.
set -euo pipefail
cd "$(dirname "$0")"

started=$(date +%s)
# Each step's header says how long the run has taken so far, so the growth of a step shows.
step() { printf '\n== %s (at %d s)\n' "$*" $(( $(date +%s) - started )); }

step "toolchain"
rustup target add thumbv7em-none-eabihf
rustup component add rustfmt clippy llvm-tools
cargo --version
# The emulated board (QEMU's mps2-an386) and the instruction-counting plugin it is measured with.
scripts/need.sh qemu-system-arm gcc python3
# flip-link, the boards' linker (.cargo/config.toml): the stack below the statics, so that an
# overflow faults instead of writing over them. Built once (some ten seconds).
FLIP_LINK_VERSION=0.1.12
if ! cargo install --list | grep -qx "flip-link v$FLIP_LINK_VERSION:"; then
    cargo install flip-link --version "$FLIP_LINK_VERSION" --locked --quiet
fi

step "formatting"
cargo fmt --all -- --check

step "lints, documentation and the core's other builds: started in the background (nice 19)"
# They need nothing the other steps make, and the machine idles in places: the micro-VM of the
# HIL suite keeps about one of the two cores busy, test binaries run one after another. So they
# run beside the other steps, at the lowest priority (they take only what those leave) and in a
# target directory of their own (no build lock shared with the steps); the run waits for them at
# its end and prints their log if one failed. What they are:
# - scripts/lint.sh: clippy on the host crates (every target) and on the boards' crates for
#   thumbv7em-none-eabihf, warnings denied; rustdoc with warnings denied (a broken or ambiguous
#   intra-doc link fails);
# - the core without its mechanisms (`--no-default-features`: no BLE, dynamics, filters or schema
#   server), as the minimal board build has it: it refuses tables that use them instead of
#   running them without;
# - each benchmark once, in test mode;
# - the fuzz targets' build (nightly, with the sanitizer): the fuzzing step runs them after the
#   HIL suite, from this build.
target="${CARGO_TARGET_DIR:-target}"
mkdir -p "$target"
background_log="$target/background-checks.log"
background_checks() {
    set -euo pipefail
    # setsid below made a new session, which the kernel's autogroup scheduling (on by default)
    # weighs equal to the foreground's whatever the niceness inside it: give the group itself
    # nice 19 (where there is no autogroup, the process's niceness is what counts).
    echo 19 > /proc/self/autogroup 2> /dev/null || true
    local own="$target/background"
    echo "== scripts/lint.sh"
    CARGO_TARGET_DIR="$own" scripts/lint.sh
    echo "== the core without its mechanisms"
    CARGO_TARGET_DIR="$own" cargo test -p pab-core --no-default-features --lib --locked
    echo "== benchmarks, once each in test mode"
    CARGO_TARGET_DIR="$own" cargo test -p pab-core --benches --locked
    # The fuzz workspace (fuzz/) has a target directory of its own, which no step shares.
    echo "== the fuzz targets' build (scripts/fuzz.sh --build-only)"
    scripts/fuzz.sh --build-only
}
# setsid: a process group of its own, so that a failing step stops it too (the EXIT trap).
export -f background_checks
export target
setsid nice -n 19 bash -c background_checks > "$background_log" 2>&1 &
background=$!
trap 'kill -- -"$background" 2> /dev/null || true' EXIT
echo "in the background: scripts/lint.sh, the core without dynamics, the benchmarks, the fuzz" \
    "targets' build ($background_log)"

step "the book (docs/: mdBook, its links and anchors, the README's)"
# mdBook, the Rust ecosystem's book tool, built once without its server and file watcher (about
# two minutes); the build fails on a page missing from SUMMARY.md or a broken include.
MDBOOK_VERSION=0.5.4
if ! mdbook --version 2>/dev/null | grep -qx "mdbook v$MDBOOK_VERSION"; then
    cargo install mdbook --version "$MDBOOK_VERSION" --locked --no-default-features --quiet
fi
# mdBook reports a broken link target or a missing file as a warning and still exits 0: any
# WARN or ERROR line fails the step.
mkdir -p target
if ! mdbook build docs > target/mdbook.log 2>&1 || grep -E "WARN|ERROR" target/mdbook.log; then
    cat target/mdbook.log
    echo "mdbook: the book does not build cleanly (above)" >&2
    exit 1
fi
# Every relative link and #anchor of the README, the changelog and the book resolves, the book's
# pages link only inside docs/ and are all in its summary, and none names a past issue.
python3 scripts/check-docs.py

step "pab-core for the boards (thumbv7em-none-eabihf)"
cargo build -p pab-core --release --target thumbv7em-none-eabihf --locked
cargo build -p pab-storage --release --target thumbv7em-none-eabihf --locked

step "firmware for the NUCLEO-G474RE (pab-fw-g474), the NUCLEO-F446RE (pab-fw-f446) and the emulated Cortex-M4 (pab-fw-an386); the NUCLEO boards' bootloaders (sized by scripts/firmware-size.sh)"
# The `firmware` profile: what is flashed (see the root Cargo.toml). One board a command: their
# features would unify in one build.
cargo build -p pab-fw-g474 --profile firmware --target thumbv7em-none-eabihf --locked
cargo build -p pab-fw-f446 --profile firmware --target thumbv7em-none-eabihf --locked
cargo build -p pab-fw-an386 --profile firmware --target thumbv7em-none-eabihf --locked
scripts/firmware-size.sh

step "a node on a driver that is not embassy's: pab-own-driver for an STM32F405 (bxCAN, no embassy)"
# The example of docs/your-own-driver.md: stm32f4xx-hal's bxCAN driver through pab_app::EmbeddedCan,
# pab_app::PollLoop in a superloop. Its node code is tested on the host in `cargo test` (over
# pab-app's test bus); here its firmware is built, and its dependency tree must hold no embassy
# crate (the point of the example).
cargo build -p pab-own-driver --features board --profile firmware --target thumbv7em-none-eabihf --locked
if cargo tree -p pab-own-driver --features board -e normal --target thumbv7em-none-eabihf --locked \
    --prefix none | grep '^embassy'; then
    echo "pab-own-driver's firmware depends on embassy (above)" >&2
    exit 1
fi

step "no panic call site of pab_core, pab_app, pab_storage or pab_slcan in the board firmware"
# The board firmwares built with their panic locations (in target/panic-check: the check needs
# each site's own call; scripts/panic-check.sh says why), disassembled, and every branch to a
# panic entry point attributed through its inline chain: fails on any such site. In the
# foreground: the one run with it in the background, whose builds then overlapped the HIL suite,
# read the emergency stop's latency there at 10.4 ms of its 15 ms bound (2 to 6 ms before).
scripts/panic-check.sh

step "Cortex-M4 instructions per frame (emulated board, QEMU mps2-an386)"
# Exact counts (a TCG plugin), so this is a deterministic check, not a timing: it fails if a goal
# is exceeded, if a goal not yet met gets worse, or if the method's own checks (loops of known
# length, SysTick under -icount) disagree.
scripts/cortex-m4-cost.sh --check

step "tests"
cargo test --locked
# The book's "Your own board" example: the node over stand-ins for a CAN driver, a flash and a
# watchdog; it checks what the table says happens and exits 1 otherwise.
cargo run -q -p pab-app --example your_own_board --locked

step "examples (and the release builds the HIL suite runs: hil-sim/run-hil --build-only)"
# pabctl and pab-node in release, the emulated board's firmware and its single-bank test build:
# built here, where the build has the machine, so that the HIL step below builds nothing.
hil-sim/run-hil --build-only
pabctl="$target/release/pabctl"
out="$target/examples"
mkdir -p "$out"
# examples/dynamics/: DESIGN's competitive-dynamics scenarios, one small network each
# (tests/tests/dynamics_scenarios.rs asserts their orderings and bounds); all eight took 7 s
# with an unoptimised pabctl, plots included.
for network in examples/*.toml examples/dynamics/*.toml; do
    name=${network#examples/}
    name=${name%.toml}
    mkdir -p "$(dirname "$out/$name")"
    "$pabctl" check "$network" > "$out/$name.check.txt"
    "$pabctl" compile "$network" -o "$out/$name" > "$out/$name.compile.txt"
    # A file with a schema server's [client] also writes its schema trace (--plot draws its run).
    schema=()
    if grep -q '^\[client\]' "$network"; then schema=(--schema-trace "$out/$name.schema.csv"); fi
    "$pabctl" sim "$network" --trace "$out/$name.csv" --plot "$out/$name.png" "${schema[@]}" \
        --candump "$out/$name.log" > "$out/$name.sim.txt"
    echo "$network: consistent, compiled, simulated ($out/$name.png)"
done
# The same plot as SVG (same drawing code, texts as text): one with gates and one with Ayllu's
# windows; each must be one <svg> element.
for name in door-dynamics subsumption; do
    "$pabctl" sim "examples/$name.toml" --plot "$out/$name.svg" > /dev/null
    if [[ "$(head -c 5 "$out/$name.svg")" != "<svg " ]] || ! tail -c 8 "$out/$name.svg" | grep -q '</svg>'; then
        echo "$out/$name.svg: not an SVG" >&2
        exit 1
    fi
    echo "examples/$name.toml: drawn as SVG ($out/$name.svg)"
done

step "hardware-in-the-loop harness, host-side unit tests (hil-sim/unit)"
# The venv holds the pinned requirements-dev.txt (pytest, python-can, cantools); creating it needs
# PyPI once. A missing python3, venv or package fails the run: these steps are never skipped.
venv=$(scripts/python-env.sh)
# The micro-VM's accelerator decision against stand-ins for QEMU, and the guest kernel's module
# resolution: no QEMU, no bus.
"$venv/bin/python" -m pytest hil-sim/unit -q

step "the schema server's Python client (client/python/tests)"
# pab_client's builders against the golden vectors the Rust builders write
# (lang/tests/client_golden.rs checks that file in `cargo test`), its frames, and the client on
# python-can's virtual bus against a scripted node: no kernel CAN, no QEMU.
"$venv/bin/python" -m pytest client/python/tests -q

step "ISO-TP on CAN FD: the golden frames are python can-isotp's (scripts/isotp_fd_golden.py)"
# core/tests/isotp_fd.rs checks pab-core's CAN FD encoders and decoder against the frames
# can-isotp sends (core/tests/fixtures/isotp_fd_can_isotp.txt); here can-isotp writes them again,
# and they must be the committed ones.
"$venv/bin/python" scripts/isotp_fd_golden.py | diff -u core/tests/fixtures/isotp_fd_can_isotp.txt -

step "emulated Cortex-M4: the time driver across TIMER0's wraps (pab-an386-timecheck, QEMU)"
# 400 s of virtual time (-icount) with the clock read without pause around each 100 s wrap.
cargo run --profile firmware -p pab-fw-an386 --target thumbv7em-none-eabihf --bin pab-an386-timecheck \
    --locked -- -icount shift=10,sleep=off

step "emulated Cortex-M4: pab-builtins' memcpy, memset, memcmp, memmove and 64-bit division (pab-an386-builtinscheck, QEMU)"
# Copies, fills, comparisons and overlapping moves at every alignment and length up to 72 bytes,
# the bytes around untouched; divisions against a reference on edge cases and 200 000 random pairs. A broken loop
# could spin for ever: the timeout turns that into a failure.
timeout 300 cargo run --profile firmware -p pab-fw-an386 --target thumbv7em-none-eabihf \
    --bin pab-an386-builtinscheck --locked

step "emulated Cortex-M4: the watchdog restarts a hung node loop, an overflowed stack faults (scripts/watchdog-test.sh, QEMU)"
# A hang-test build spins in its node loop on a trigger frame; the CMSDK APB watchdog must reset
# the machine and the node boot again with its stored table. The production build has no trigger.
scripts/watchdog-test.sh

step "emulated Cortex-M4: the bootloader installs, checks, swaps, reverts and refuses updates (scripts/boot-test.sh, QEMU)"
# pab-boot-an386 (embassy-boot) with a test application behind it: a signed update swapped in and
# confirmed; one unconfirmed (a reset, a watchdog's reset) reverted; another key's, another
# board's, a changed one refused with the verdict's code and never swapped; the node firmware
# booted from the active partition. Fails if the bootloader outgrows its 32 KiB.
scripts/boot-test.sh

step "emulated Cortex-M4: a reset at every flash operation of the bootloader's swap and revert (scripts/boot-reset-test.sh, QEMU)"
# The bootloader's test build (`reset-test`) resets the board in place of its N-th partition
# operation, one QEMU run per N: the factory install, the verdict, the swap's mark, every page
# copy, progress record and erase of the swap, then of the revert. Each run must end on v1 or v2
# as the step implies, with the expected messages. About 20 s.
scripts/boot-reset-test.sh

step "emulated Cortex-M4 with a key: scripts/keyed-board-test.sh (QEMU)"
# A key page from `pabctl keygen`/`pabctl keypage` planted at the board's key page: keyed in its
# heartbeat, plain configuration refused, pabctl's keyed push taken, a new boot salt after reset.
scripts/keyed-board-test.sh

step "the DBC export and the cross-runner test: started beside the HIL suite (nice 19)"
# Both are exact comparisons of outputs (no timing), and the HIL suite's micro-VM leaves about
# one core idle: they run beside it, at the lowest priority. The HIL suite builds nothing (its
# builds were made in the examples step), so nothing waits for cargo's build lock. Their log
# is printed if they fail; the run waits for them after the suite.
beside_log="$target/beside-hil.log"
beside_hil() {
    set -euo pipefail
    echo 19 > /proc/self/autogroup 2> /dev/null || true
    echo "== DBC export, decoded by cantools"
    # Every example's simulated bus (the examples step's --candump), decoded strictly by the command
    # a user types (`python -m cantools decode NET.dbc < bus.log`, no --no-strict), with the claims of
    # the capture listed (--claims-from); a schema server's examples put no frame on the simulated
    # bus, and their databases still load strictly. Then the committed capture of the HIL suite's
    # real bus (heartbeats, table transfers, re-published frames) with Take and Return's database.
    pairs=()
    for network in examples/*.toml; do
        name=$(basename "$network" .toml)
        claims=()
        if [ -s "$out/$name.log" ]; then claims=(--claims-from "$out/$name.log"); fi
        "$pabctl" dbc "$network" "${claims[@]}" -o "$out/$name.dbc"
        pairs+=("$out/$name.dbc" "$out/$name.log")
    done
    "$pabctl" dbc examples/take-and-return.toml -o "$out/take-and-return-hil.dbc"
    pairs+=("$out/take-and-return-hil.dbc" host-tools/tests/fixtures/take-and-return-hil.log)
    "$venv/bin/python" host-tools/tests/dbc_strict.py "${pairs[@]}"
    # A schema server's sensor topics, one of each kind of field (the fixture's comment).
    "$pabctl" dbc host-tools/tests/fixtures/sensors.toml -o "$out/sensors.dbc"
    "$venv/bin/python" host-tools/tests/dbc_cantools.py "$out/take-and-return.dbc" \
        "$out/multi-target-observation.dbc" "$out/door-dynamics.dbc" "$out/tour-guide.dbc" \
        "$out/assembly.dbc" "$out/sensors.dbc" "$out/value-ports.dbc" "$out/take-and-return-fd.dbc"
    echo "== identical decisions on every runner: scripts/cross-runner.sh"
    # The same frames (every example's bus, the committed HIL log) through the simulator, the Linux
    # node's application and pab-an386-replay on QEMU's mps2-an386 (Cortex-M4): byte-identical
    # records of every verdict. (The first two also run in `cargo test`.) Installs qemu-system-arm
    # with apt-get if it is missing; never skipped.
    scripts/cross-runner.sh
}
export -f beside_hil
export venv pabctl out
setsid nice -n 19 bash -c beside_hil > "$beside_log" 2>&1 &
beside=$!
trap 'kill -- -"$background" -"$beside" 2> /dev/null || true' EXIT
echo "beside the HIL suite: the DBC export decoded by cantools, scripts/cross-runner.sh ($beside_log)"

step "hardware-in-the-loop: hil-sim/run-hil --no-build"
# pab-node processes on a SocketCAN vcan0, the Take and Return behaviours and world in python-can.
# Where the kernel has no vcan (this CI's), the suite runs in a QEMU micro-VM that has one; run-hil
# says which way it took, and fails the run when a HIL test fails.
hil-sim/run-hil --no-build

step "the DBC export and the cross-runner test (started beside the HIL suite)"
if ! wait "$beside"; then
    cat "$beside_log"
    echo "the DBC export or the cross-runner test failed (above; log: $beside_log)" >&2
    exit 1
fi
cat "$beside_log"

step "the background's lints, documentation, core builds and fuzz build (started at the beginning)"
if ! wait "$background"; then
    cat "$background_log"
    echo "the background checks failed (above; log: $background_log)" >&2
    exit 1
fi
trap - EXIT
grep -E "^== |^lint:|^test result|Finished" "$background_log"

step "fuzzing: every target for 15 s (scripts/fuzz.sh, nightly + cargo-fuzz)"
# `cargo test` above replayed the committed corpus (fuzz/corpus) and any reproducers
# (fuzz/artifacts) on stable; this runs libFuzzer itself from that corpus, briefly: a crash, a hang
# (20 s) or running out of memory fails the run. Long campaigns: docs/fuzzing.md.
# From the background's build: its build step has nothing left to do.
scripts/fuzz.sh 15

step "the fresh HIL log of Take and Return through the three runners"
scripts/cross-runner.sh "${CARGO_TARGET_DIR:-target}/hil/test_phases_a_to_f_end_with_the_object_handed_to_the_person/bus.log"

step "all passed in $(( $(date +%s) - started )) s"
