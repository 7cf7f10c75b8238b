"""The micro-VM's accelerator decision, with a stand-in for QEMU (fake_qemu.py): every way KVM can
fail before the guest starts falls back to software emulation; a failure after it started is the
job's; PAB_HIL_ACCEL forces either accelerator. No QEMU, no kernel: these run on any host."""

from __future__ import annotations

import os
import stat
import sys
import time
from pathlib import Path

import pytest

from pab_hil.vm.boot import KVM, TCG, VmError, accel_mode, boot

FAKE = Path(__file__).with_name("fake_qemu.py")
PROBE_S = 1.5  # the KVM probe, shortened: the stand-in that hangs must cost seconds, not minutes


@pytest.fixture
def qemu(tmp_path, monkeypatch):
    """Puts the stand-in on PATH as qemu-system-x86_64; returns (out_dir, invocations())."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    stand_in = bin_dir / "qemu-system-x86_64"
    stand_in.write_text(f"#!/bin/sh\nexec {sys.executable} {FAKE} \"$@\"\n")
    stand_in.chmod(stand_in.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    log = tmp_path / "invocations"
    monkeypatch.setenv("FAKE_QEMU_LOG", str(log))
    out = tmp_path / "out"
    out.mkdir()

    def invocations() -> list[str]:
        return log.read_text().split() if log.exists() else []

    return out, invocations


def run(out: Path, mode: str = "auto", kvm: bool = True):
    return boot(Path("/nonexistent/vmlinux"), Path("/nonexistent/initrd"), out, timeout_s=30,
                mode=mode, kvm_available=kvm, probe_s=PROBE_S, boot_timeout_s=10)


@pytest.mark.parametrize("failure, reason", [
    ("exit", "QEMU exited with status 1 before the guest started"),
    ("abort", "QEMU reported an error: error: failed to set MSR 0x10a to 0x69"),
    ("error", "QEMU reported an error: error: could not set up the KVM vCPU"),
    ("hang", f"no sign of life from the guest within {PROBE_S:.0f} s"),
])
def test_any_kvm_failure_before_the_guest_starts_falls_back_to_tcg(qemu, monkeypatch, capsys,
                                                                    failure, reason):
    out, invocations = qemu
    monkeypatch.setenv("FAKE_QEMU_KVM", failure)
    monkeypatch.setenv("FAKE_QEMU_TCG", "pass")
    started = time.monotonic()
    outcome = run(out)
    assert (outcome.status, outcome.accel) == (0, TCG)
    assert invocations() == ["kvm", "tcg"]
    said = [line for line in capsys.readouterr().out.splitlines() if "falling back" in line]
    assert said == [f"run-hil: KVM failed before the guest started ({reason}): "
                    "falling back to software emulation (TCG)"]
    # An error line stops the waiting at once; only silence waits for the probe.
    assert time.monotonic() - started < (PROBE_S + 5 if failure == "hang" else PROBE_S)


def test_a_silent_abort_is_named_by_its_signal(qemu, monkeypatch, capsys):
    out, invocations = qemu
    monkeypatch.setenv("FAKE_QEMU_KVM", "crash")
    outcome = run(out)
    assert (outcome.status, outcome.accel) == (0, TCG)
    assert "(QEMU was killed by SIGABRT before the guest started): falling back" in \
        capsys.readouterr().out


def test_a_warning_is_not_a_failure(qemu, monkeypatch):
    out, invocations = qemu
    monkeypatch.setenv("FAKE_QEMU_KVM", "warn")
    outcome = run(out)
    assert (outcome.status, outcome.accel) == (0, KVM)
    assert invocations() == ["kvm"]


def test_a_kvm_guest_that_boots_and_passes_stays_on_kvm(qemu, monkeypatch):
    out, invocations = qemu
    monkeypatch.setenv("FAKE_QEMU_KVM", "pass")
    outcome = run(out)
    assert (outcome.status, outcome.accel) == (0, KVM)
    assert invocations() == ["kvm"]
    assert "first test" in (out / "vm-boot.txt").read_text()


def test_a_job_that_fails_under_kvm_is_the_jobs_failure_not_a_fallback(qemu, monkeypatch):
    out, invocations = qemu
    monkeypatch.setenv("FAKE_QEMU_KVM", "fail")
    outcome = run(out)
    assert (outcome.status, outcome.accel) == (3, KVM)
    assert invocations() == ["kvm"]


def test_a_guest_that_dies_after_its_first_line_is_an_error_not_a_fallback(qemu, monkeypatch):
    out, invocations = qemu
    monkeypatch.setenv("FAKE_QEMU_KVM", "die")
    with pytest.raises(VmError, match="stopped without the job's exit status"):
        run(out)
    assert invocations() == ["kvm"]


def test_tcg_that_fails_too_is_an_error_naming_why(qemu, monkeypatch):
    out, invocations = qemu
    monkeypatch.setenv("FAKE_QEMU_KVM", "abort")
    monkeypatch.setenv("FAKE_QEMU_TCG", "exit")
    with pytest.raises(VmError, match="did not start: QEMU exited with status 1 before the guest"):
        run(out)
    assert invocations() == ["kvm", "tcg"]


def test_without_usable_kvm_only_tcg_is_tried(qemu, monkeypatch):
    out, invocations = qemu
    monkeypatch.setenv("FAKE_QEMU_TCG", "fail")
    outcome = run(out, kvm=False)
    assert (outcome.status, outcome.accel) == (3, TCG)
    assert invocations() == ["tcg"]


def test_pab_hil_accel_tcg_never_tries_kvm(qemu, monkeypatch):
    out, invocations = qemu
    monkeypatch.setenv("FAKE_QEMU_KVM", "pass")
    outcome = run(out, mode="tcg")
    assert outcome.accel == TCG
    assert invocations() == ["tcg"]


def test_pab_hil_accel_kvm_never_falls_back(qemu, monkeypatch):
    out, invocations = qemu
    monkeypatch.setenv("FAKE_QEMU_KVM", "abort")
    with pytest.raises(VmError, match="KVM failed before the guest started: QEMU reported an error"):
        run(out, mode="kvm")
    assert invocations() == ["kvm"]
    with pytest.raises(VmError, match="/dev/kvm is missing or not usable"):
        run(out, mode="kvm", kvm=False)
    assert invocations() == ["kvm"]


def test_a_stale_status_from_an_earlier_run_is_not_taken(qemu, monkeypatch):
    out, _ = qemu
    (out / "job.status").write_text("0\n")
    monkeypatch.setenv("FAKE_QEMU_KVM", "die")
    with pytest.raises(VmError, match="without the job's exit status"):
        run(out)


@pytest.mark.parametrize("value, mode", [(None, "auto"), ("", "auto"), ("TCG", "tcg"),
                                         ("kvm", "kvm"), (" auto ", "auto")])
def test_pab_hil_accel_values(value, mode):
    environ = {} if value is None else {"PAB_HIL_ACCEL": value}
    assert accel_mode(environ) == mode


def test_a_mistyped_pab_hil_accel_is_an_error_that_lists_the_choices():
    with pytest.raises(VmError, match="PAB_HIL_ACCEL='kmv': expected one of auto, kvm, tcg"):
        accel_mode({"PAB_HIL_ACCEL": "kmv"})
