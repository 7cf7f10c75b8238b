"""Packages from the host's apt sources, fetched and unpacked into a cache, never installed.

The micro-VM needs a kernel with SocketCAN and a static busybox. Both come from the distribution's
own archive (`apt-get download`, then `dpkg-deb -x` into the cache), so the host's installed
packages stay as they are: a host whose /bin/busybox is the dynamic build, or whose kernel has no
vcan, is not changed by running the suite.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path


class AptError(RuntimeError):
    pass


def apt(command: list[str], cwd: Path | None = None) -> str:
    """Runs an apt command without prompts; its output, or AptError with the tail of it."""
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    result = subprocess.run(command, cwd=cwd, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    if result.returncode != 0:
        raise AptError(f"`{' '.join(command)}` failed:\n{result.stdout[-3000:]}")
    return result.stdout


_updated = False


def update_once() -> None:
    """`apt-get update`, at most once per run (root only; a non-root caller gets AptError)."""
    global _updated
    if not _updated:
        apt(["apt-get", "update", "-qq"])
        _updated = True


def depends(package: str) -> list[str]:
    """The direct dependencies of `package` (first alternative of each), [] if apt does not know it."""
    result = subprocess.run(["apt-cache", "depends", package], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    found = []
    for line in result.stdout.splitlines():
        stripped = line.strip()
        if stripped.startswith("Depends:"):
            found.append(stripped.removeprefix("Depends:").strip().strip("<>"))
    return found


def known(package: str) -> bool:
    """Whether the apt lists have a candidate for `package`."""
    result = subprocess.run(["apt-cache", "policy", package], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    return "Candidate:" in result.stdout and "Candidate: (none)" not in result.stdout


def fetch_and_unpack(package: str, into: Path) -> Path:
    """Downloads `package` (the candidate version) and unpacks it into `into`/<package>.

    Retries once after `apt-get update` when the lists are missing or stale (a fresh machine's
    lists are often empty)."""
    root = into / package
    marker = root / ".unpacked"
    if marker.exists():
        return root
    download = into / "download"
    download.mkdir(parents=True, exist_ok=True)
    for stale in download.glob("*.deb"):
        stale.unlink()
    try:
        apt(["apt-get", "download", package], cwd=download)
    except AptError:
        update_once()
        apt(["apt-get", "download", package], cwd=download)
    debs = sorted(download.glob(f"{package}_*.deb"))
    if len(debs) != 1:
        raise AptError(f"apt-get download {package} left {len(debs)} packages in {download}")
    if root.exists():
        shutil.rmtree(root)
    subprocess.run(["dpkg-deb", "-x", str(debs[0]), str(root)], check=True)
    debs[0].unlink()
    marker.write_text(package + "\n")
    return root


def architecture() -> str:
    """The host's Debian architecture (amd64, arm64, ...)."""
    result = subprocess.run(["dpkg", "--print-architecture"], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    return result.stdout.strip()
