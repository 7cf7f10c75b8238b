"""How much slower than the reference machine this one runs the suite: factors of at least 1 that
the tests' allowances are multiplied by.

An allowance is what a loaded or emulated machine adds to the product's own timing: the
scheduler's delay before a node reads a frame, the frames queued on the emulated board's serial
line. The product's own figures (a period, a decay time, a lease) are never scaled: they are what
the network file says. Two measures, each against the same measure on a quiet 2-core machine of
the kind CI runs on, under software emulation (TCG):

- the micro-VM's boot, kernel start to the job (`PAB_VM_BOOT_S`, written by the guest's /init:
  run-hil prints it as "job starting at ... s"); on a machine's own vcan0, where no emulation
  stands between the suite and the kernel, the factor is 1;
- the emulated board's boot, QEMU started to its first heartbeat on the bus (the figure
  `emulated-board` `boot_to_first_heartbeat_s`): its serial line and its QEMU, which run on the
  host beside the micro-VM.

A faster machine gets 1, never less: the allowances are what the suite was written with.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping

#: s: the micro-VM's boot on the reference machine (quiet, TCG): 4.06 and 4.19 s measured.
REFERENCE_VM_BOOT_S = 4.2
#: s: the emulated board's boot on the reference machine, from the micro-VM: 1.06 s measured.
REFERENCE_BOARD_BOOT_S = 1.1
VM_BOOT_ENV = "PAB_VM_BOOT_S"


def machine_factor(environ: Mapping[str, str] = os.environ) -> float:
    """The micro-VM's boot against the reference's, at least 1; 1 outside the micro-VM."""
    text = environ.get(VM_BOOT_ENV, "").strip()
    try:
        boot = float(text)
    except ValueError:
        return 1.0
    return max(1.0, boot / REFERENCE_VM_BOOT_S) if 0 < boot < math.inf else 1.0


def board_factor(boot_s: float) -> float:
    """The emulated board's boot against the reference's, at least 1."""
    return max(1.0, boot_s / REFERENCE_BOARD_BOOT_S) if 0 < boot_s < math.inf else 1.0
