#!/usr/bin/env bash
# Makes sure commands are on this machine, installing their Debian packages if they are not:
#   scripts/need.sh qemu-system-arm gcc python3
# Each argument is a command, or COMMAND=PACKAGE where the package is named otherwise
# (qemu-system-arm's is qemu-system-arm). Missing ones are installed with one apt-get (after an
# `apt-get update`) when run as root; otherwise the script fails naming the packages to install.
set -euo pipefail

missing_packages=()
for spec in "$@"; do
    command="${spec%%=*}"
    package="${spec#*=}"
    if ! command -v "$command" > /dev/null; then
        missing_packages+=("$package")
    fi
done
[ ${#missing_packages[@]} -eq 0 ] && exit 0

if [ "$(id -u)" -ne 0 ] || ! command -v apt-get > /dev/null; then
    echo "need: missing ${missing_packages[*]}: install them" \
        "(Debian/Ubuntu: sudo apt-get install ${missing_packages[*]})" >&2
    exit 2
fi
echo "need: installing ${missing_packages[*]} with apt-get" >&2
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq --no-install-recommends "${missing_packages[@]}" > /dev/null
