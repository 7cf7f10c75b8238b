#!/usr/bin/env bash
# Cargo's runner for thumbv7em-none-eabihf (.cargo/config.toml): `cargo run --target
# thumbv7em-none-eabihf -p <board>` ends here with the ELF as first argument.
#   - the emulated board's binaries (pab-fw-an386*, pab-an386-*) run in QEMU's mps2-an386, with
#     semihosting (their console and exit status) on this terminal; extra arguments go to QEMU;
#     PAB_KEY_PAGE=FILE plants FILE (`pabctl keypage KEY -o FILE`) at the emulated board's key
#     page, 0x0004_E000 (QEMU's loader, again at every system reset);
#   - pab-fw-f446 and its bootloader pab-boot-f446 are flashed to a NUCLEO-F446RE with probe-rs
#     (chip STM32F446RETx), which prints the firmware's defmt log;
#   - anything else is flashed to a NUCLEO-G474RE with probe-rs, which prints its defmt log.
set -euo pipefail
elf="$1"
shift
case "$(basename "$elf")" in
    pab-fw-an386* | pab-an386-*)
        if ! command -v qemu-system-arm > /dev/null; then
            echo "run-thumbv7em: qemu-system-arm is missing (Debian: apt-get install qemu-system-arm)" >&2
            exit 2
        fi
        key_page=()
        if [ -n "${PAB_KEY_PAGE:-}" ]; then
            if [ ! -f "$PAB_KEY_PAGE" ]; then
                echo "run-thumbv7em: PAB_KEY_PAGE=$PAB_KEY_PAGE: no such file (pabctl keypage KEY -o FILE)" >&2
                exit 2
            fi
            key_page=(-device "loader,file=$PAB_KEY_PAGE,addr=0x4e000,force-raw=on")
        fi
        exec qemu-system-arm -M mps2-an386 -nographic -monitor none \
            -semihosting-config enable=on,target=native -kernel "$elf" "${key_page[@]}" "$@"
        ;;
    pab-fw-f446* | pab-boot-f446*)
        exec probe-rs run --chip STM32F446RETx "$elf" "$@"
        ;;
    *)
        exec probe-rs run --chip STM32G474RETx "$elf" "$@"
        ;;
esac
