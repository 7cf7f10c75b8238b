#!/usr/bin/env bash
# What the board firmware costs, per board and per feature set, from its build with the `firmware`
# profile (the one that is flashed; see the root Cargo.toml): flash (text + data), static RAM
# (data + bss) and the deepest stack (scripts/stack-depth.py says how it is measured).
#   scripts/firmware-size.sh                 a line per board and feature set
#   scripts/firmware-size.sh --json          the same as one JSON array
#   scripts/firmware-size.sh --increments    also the minimal build plus each mechanism alone
#                                            (what each costs: docs/footprint.md)
# Feature sets: "full" (every mechanism, what is flashed), "minimal" (`--no-default-features`:
# arbitration, the protocol, the table store and keys), with --increments "ble", "dynamics",
# "filters", "schema" (minimal plus that one), and the NUCLEO-G474RE's "full+identity"
# (identity and configuration over the bus, not flashed: it does not fit yet, and the line says
# by how much); "ble+dynamics+filters+update", the node that takes firmware updates over the bus
# behind its bootloader (the emulated board's and the NUCLEO-G474RE's: every mechanism but the
# schema server, with identity), the emulated board's beside the same set with identity alone,
# the update's cost being the difference; the NUCLEO-G474RE's "ble+dynamics+filters+fd" (CAN FD,
# src/can_fd.rs) beside the same set classic, "ble+dynamics+filters", CAN FD's cost being the
# difference. Each entry: flash, ram_static, stack_peak, ram_peak
# (static + deepest stack).
#
# Then the NUCLEO boards' bootloaders (pab-boot-g474, pab-boot-f446: firmware/boot/), each a
# line of its flash (text + data) against its goal, 24 KiB, and its region, 32 KiB (memory.x;
# on stderr with --json).
#
# Fails when a full build, a build that takes updates or the CAN FD build takes more than 64 KiB
# of flash (the
# latter must also fit its bootloader's active partition, less the manifest: its memory-boot.x,
# which the linker enforces), when a bootloader does not fit its 32 KiB region, or when any
# build's deepest chain of calls leaves less than 8 KiB of its stack. The other goals
# (docs/footprint.md) are printed, not enforced. Each build's ELF is kept in
# target/footprint/<package>-<set>; the flashed (full) build is put back where the other scripts
# and the HIL suite read it. Cargo keeps each feature set's artifacts apart, so a second run
# rebuilds nothing.
# Needs llvm-size from rustup's llvm-tools component (installed here if missing).
set -euo pipefail
cd "$(dirname "$0")/.."

json=false
increments=false
for arg in "$@"; do
    case "$arg" in
        --json) json=true ;;
        --increments) increments=true ;;
        -h|--help) sed -n '2,25p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) echo "firmware-size: unknown argument '$arg' (--json, --increments, --help)" >&2; exit 2 ;;
    esac
done

target="${CARGO_TARGET_DIR:-target}"
size="$(rustc --print sysroot)/lib/rustlib/$(rustc -vV | sed -n 's/^host: //p')/bin/llvm-size"
if [ ! -x "$size" ]; then
    rustup component add llvm-tools >&2
fi
mkdir -p "$target/footprint"
rows="$target/footprint/rows.tsv"
: > "$rows"

# measure PACKAGE SET CARGO_FEATURE_ARGS...
measure() {
    local package="$1" set="$2"
    shift 2
    cargo build -q -p "$package" --profile firmware --target thumbv7em-none-eabihf --locked "$@"
    local elf="$target/footprint/$package-$set"
    cp "$target/thumbv7em-none-eabihf/firmware/$package" "$elf"
    local text data bss
    read -r text data bss < <("$size" "$elf" | awk 'NR == 2 { print $1, $2, $3 }')
    local stack
    if ! stack=$(python3 scripts/stack-depth.py --json "$elf"); then
        python3 scripts/stack-depth.py "$elf" >&2 || true
        exit 1
    fi
    printf '%s\t%s\t%d\t%d\t%s\n' "$package" "$set" $(( text + data )) $(( data + bss )) \
        "$stack" >> "$rows"
}

boards=(pab-fw-g474 pab-fw-f446 pab-fw-an386)
for package in "${boards[@]}"; do
    measure "$package" minimal --no-default-features
    if "$increments"; then
        for mechanism in ble dynamics filters schema; do
            measure "$package" "$mechanism" --no-default-features --features "$mechanism"
        done
    fi
    if [ "$package" = pab-fw-g474 ]; then
        measure "$package" full+identity --features identity
        # The node that takes updates over the bus, behind the bootloader: the emulated board's
        # set (below), without the schema server, which with identity and the update does not
        # fit 64 KiB.
        measure "$package" ble+dynamics+filters+update --no-default-features \
            --features ble,dynamics,filters,update
        # CAN FD (FDCAN in FD mode, frames of 64 bytes through the node), beside the same set
        # classic: the full build has no flash to spare for it.
        measure "$package" ble+dynamics+filters --no-default-features \
            --features ble,dynamics,filters
        measure "$package" ble+dynamics+filters+fd --no-default-features \
            --features ble,dynamics,filters,fd
    fi
    # The node that takes updates over the bus (behind the bootloader, with identity: what
    # scripts/boot-test.sh runs), without the schema server: with it, it does not fit the
    # active partition yet. The update's own cost is this less the same set with identity.
    if [ "$package" = pab-fw-an386 ]; then
        measure "$package" ble+dynamics+filters+identity --no-default-features \
            --features ble,dynamics,filters,identity --bin pab-fw-an386
        measure "$package" ble+dynamics+filters+update --no-default-features \
            --features ble,dynamics,filters,update --bin pab-fw-an386
    fi
    # Last: the flashed build is the one left in place.
    measure "$package" full
done

# The NUCLEO boards' bootloaders: flash against the goal (printed) and the region (enforced:
# the linker refuses what overflows memory.x, but a region that grew by mistake would not).
boot_over=0
boot_lines=()
for boot in pab-boot-g474 pab-boot-f446; do
    cargo build -q -p "$boot" --profile firmware --target thumbv7em-none-eabihf --locked
    read -r text data _ < <("$size" "$target/thumbv7em-none-eabihf/firmware/$boot" | awk 'NR == 2 { print $1, $2, $3 }')
    flash=$(( text + data ))
    if [ "$flash" -le 24576 ]; then goal="$(( 24576 - flash )) under"; else goal="$(( flash - 24576 )) OVER"; fi
    line="$boot bootloader flash $flash (text $text + data $data; goal 24576: $goal; region 32768)"
    boot_lines+=("$line")
    if [ "$flash" -gt 32768 ]; then
        echo "firmware-size: $boot takes $flash bytes of flash, more than its 32 KiB region" >&2
        boot_over=1
    fi
done

status=0
python3 - "$rows" "$json" <<'EOF' || status=$?
import json
import sys

rows, as_json = sys.argv[1], sys.argv[2] == "true"
BOARDS = {
    "pab-fw-g474": "NUCLEO-G474RE",
    "pab-fw-f446": "NUCLEO-F446RE",
    "pab-fw-an386": "emulated Cortex-M4, QEMU mps2-an386",
}
FLASH = 65536
entries = []
for line in open(rows):
    package, feature_set, flash, ram, stack = line.rstrip("\n").split("\t")
    stack = json.loads(stack)
    entries.append({
        "board": package,
        "set": feature_set,
        "flash": int(flash),
        "ram_static": int(ram),
        "stack_peak": stack["stack_peak"],
        "ram_peak": int(ram) + stack["stack_peak"],
        # The largest frame of the deepest chain: what to shrink first.
        "largest_frame": max(stack["chain"], default=[0, ""]),
    })
order = ["minimal", "ble", "dynamics", "filters", "schema", "full", "full+identity",
         "ble+dynamics+filters+identity", "ble+dynamics+filters+update", "ble+dynamics+filters",
         "ble+dynamics+filters+fd"]
entries.sort(key=lambda e: (list(BOARDS).index(e["board"]), order.index(e["set"])))
# The flashed builds, those that take updates over the bus (flashed behind a bootloader) and the
# CAN FD build.
LIMITED = ("full", "ble+dynamics+filters+update", "ble+dynamics+filters+fd")
over = [e for e in entries if e["set"] in LIMITED and e["flash"] > FLASH]
if as_json:
    print(json.dumps(entries, indent=1))
else:
    print("flash = text + data; RAM = data + bss (static) + the deepest chain of calls (stack)")
    for e in entries:
        flash = e["flash"]
        room = f"{FLASH - flash} under 64 KiB" if flash <= FLASH else f"{flash - FLASH} OVER 64 KiB"
        print(f"{e['board']:13} {e['set']:29} flash {flash:6} ({room}), RAM static {e['ram_static']:6}"
              f" + stack {e['stack_peak']:6} = {e['ram_peak']:6}; largest frame {e['largest_frame'][0]}"
              f" ({e['largest_frame'][1].rsplit('::', 1)[-1]})")
    # The goals of docs/footprint.md, each said met or not (only the flash of the full builds
    # and of those that take updates is enforced).
    goals = [("full", "flash", FLASH), ("ble+dynamics+filters+update", "flash", FLASH),
             ("ble+dynamics+filters+fd", "flash", FLASH),
             ("full", "ram_peak", FLASH),
             ("minimal", "flash", 40 * 1024), ("minimal", "ram_peak", 32 * 1024)]
    for feature_set, key, limit in goals:
        missed = [f"{e['board']} {e[key]}" for e in entries
                  if e["set"] == feature_set and e[key] > limit]
        verdict = "met" if not missed else "not met: " + ", ".join(missed)
        print(f"goal: {feature_set} {key} <= {limit}: {verdict}")
for e in over:
    print(f"firmware-size: {e['board']} {e['set']} takes {e['flash']} bytes of flash, more than"
          " 64 KiB", file=sys.stderr)
sys.exit(1 if over else 0)
EOF
# The bootloaders' lines after the boards' table (on stderr with --json, whose stdout is JSON).
for line in "${boot_lines[@]}"; do
    if "$json"; then echo "$line" >&2; else echo "$line"; fi
done
[ "$status" -eq 0 ] && [ "$boot_over" -eq 0 ]
