"""The machine's speed factors (pab_hil.speed): what the suite's allowances are multiplied by."""

from pab_hil import speed


def test_the_micro_vms_boot_against_the_reference():
    reference = speed.REFERENCE_VM_BOOT_S
    assert speed.machine_factor({speed.VM_BOOT_ENV: str(2 * reference)}) == 2.0
    # A faster machine keeps the allowances the suite was written with.
    assert speed.machine_factor({speed.VM_BOOT_ENV: str(reference / 2)}) == 1.0


def test_outside_the_micro_vm_or_without_a_reading_the_factor_is_one():
    assert speed.machine_factor({}) == 1.0
    for text in ("", "soon", "0", "-3", "nan", "inf"):
        assert speed.machine_factor({speed.VM_BOOT_ENV: text}) == 1.0, text


def test_the_boards_boot_against_the_reference():
    assert speed.board_factor(3 * speed.REFERENCE_BOARD_BOOT_S) == 3.0
    assert speed.board_factor(0.1) == 1.0
    assert speed.board_factor(0.0) == 1.0
    assert speed.board_factor(float("inf")) == 1.0
