#!/usr/bin/env python3
"""A stand-in for qemu-system-x86_64 in the micro-VM's boot tests.

What it does depends on the accelerator it is asked for: FAKE_QEMU_KVM for `-enable-kvm`,
FAKE_QEMU_TCG for `-accel tcg`, each one of:

  exit    exit at once with status 1, printing nothing
  abort   print QEMU's KVM MSR error and assertion, then abort (SIGABRT), as seen on CI machines
  crash   abort at once, printing nothing
  error   print a QEMU error line, then hang (QEMU stuck after reporting)
  hang    print nothing and hang (nested KVM)
  warn    print a QEMU warning, then boot and pass
  pass    boot: print the init script's markers, write job status 0 into pab_out, exit 0
  fail    boot, the job fails: job status 3
  die     boot (first line), then exit without a job status (the guest crashed mid-job)

Every invocation appends its accelerator to FAKE_QEMU_LOG.
"""

import os
import sys
import time


def main() -> None:
    args = sys.argv[1:]
    accel = "kvm" if "-enable-kvm" in args else "tcg"
    with open(os.environ["FAKE_QEMU_LOG"], "a") as log:
        log.write(accel + "\n")
    behaviour = os.environ.get(f"FAKE_QEMU_{accel.upper()}", "pass")
    append = args[args.index("-append") + 1]
    out = next(part.split("=", 1)[1] for part in append.split() if part.startswith("pab_out="))

    def line(text: str) -> None:
        print(text, flush=True)

    def job(status: int) -> None:
        line("pab-vm: init at 0.50 s")
        line("pab-vm: job starting at 0.90 s")
        line("pab-hil: first test starting (fake)")
        with open(os.path.join(out, "job.status"), "w") as status_file:
            status_file.write(f"{status}\n")
        line(f"pab-vm: job exited with status {status}")
        sys.exit(0)

    if behaviour == "exit":
        sys.exit(1)
    if behaviour == "abort":
        line("qemu-system-x86_64: error: failed to set MSR 0x10a to 0x69")
        line("qemu-system-x86_64: ../../target/i386/kvm/kvm.c:3183: kvm_buf_set_msrs: "
             "Assertion `ret == cpu->kvm_msr_buf->nmsrs' failed.")
        os.abort()
    if behaviour == "crash":
        os.abort()
    if behaviour == "error":
        line("qemu-system-x86_64: error: could not set up the KVM vCPU")
        time.sleep(3600)
    if behaviour == "hang":
        time.sleep(3600)
    if behaviour == "warn":
        line("qemu-system-x86_64: warning: host doesn't support requested feature")
        job(0)
    if behaviour == "pass":
        job(0)
    if behaviour == "fail":
        job(3)
    if behaviour == "die":
        line("pab-vm: init at 0.50 s")
        sys.exit(0)
    sys.exit(f"fake qemu: unknown behaviour {behaviour!r}")


if __name__ == "__main__":
    main()
