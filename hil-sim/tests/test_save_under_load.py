"""A table saved while the bus is busy: the emulated board (the arm of Take and Return) takes a new
table while the bus carries some 2 000 frames a second, a tenth of them for the board, and the
test counts the frames the board lost while it stored the tables.

Run twice: with the production firmware, whose flash model is the NUCLEO-G474RE's in dual-bank
mode (the store in the bank the code does not run from: a page erase runs in the background while
the node reads frames between the save's steps), and with the test build of the G474's
single-bank layout (feature `single-bank`: every erase and program stalls the CPU, interrupts
included, while the modelled CAN controller keeps three frames and loses the rest, as the G474's
FDCAN does). The first loses no frame; the second loses frames at each page erase. Both counts go
to the test's figures.

The board's share of the load is what its serial line carries with room to spare (about 700
frames a second each way: `pab_hil.board`); the rest of the load stays off the line, as a CAN
controller's acceptance filter would keep it from the node.
"""

from __future__ import annotations

import shutil
import subprocess
import time

import can
import pytest

from pab_hil import board, nodes
from pab_hil import protocol as p
from pab_hil.nodes import NODE_IDS, TAKE_AND_RETURN
from pab_hil.observe import Recorder

ARM = NODE_IDS["arm"]
# The load: cangen bursts every GAP_MS, BOARD_BURST frames of BOARD_ID (routed to the board)
# and OTHER_BURST of OTHER_ID (not routed): 3 000 frames a second asked, 300 of them the
# board's. In bursts, so that few wake-ups carry it: cangen's pauses run long under software
# emulation (a pause per 6 frames reached three quarters of the rate asked in the quiet micro-VM,
# two fifths beside two busy processes). The rate the bus log shows is a figure of the test
# (`load_frames_per_s`) and a bound: LOAD_FPS at least, on the reference machine.
GAP_MS = 10
BOARD_ID, BOARD_BURST = 0x123, 3
OTHER_ID, OTHER_BURST = 0x7F0, 27
LOAD_FPS = 2000
# s of load before the first push and after the last answer.
SETTLE_S = 1.0
# Tables saved under load, one after the other (the node saves at most once a second).
SAVES = 5


def cangen(iface: str, ident: int, burst: int) -> subprocess.Popen:
    """can-utils' cangen: `burst` frames of `ident` every GAP_MS, 8 bytes counting up."""
    return subprocess.Popen(
        ["cangen", iface, "-g", str(GAP_MS), "-c", str(burst), "-I", f"{ident:03X}", "-L", "8",
         "-D", "i", "-p", "10"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def save_under_load(iface: str, out_dir, elf, bound) -> dict:
    """Boots the board with `elf`, pushes version 1, starts the load, pushes versions 2 to
    1 + SAVES (each stored under load: `pabctl push` reports a table Applied only once stored),
    and returns what the bus and the board said."""
    if shutil.which("cangen") is None:
        pytest.fail("cangen is missing (Debian: apt-get install can-utils)")
    routes = (f"{BOARD_ID:03X}:C00007FF",
              *board.acceptance(ARM, topics=())[1:])  # no claims needed either way
    group = nodes.Nodes(iface, out_dir, node_ids={"arm": ARM}, boards=("arm",),
                        board_routes=routes, board_elf=elf)
    recorder = Recorder(iface, out_dir / "bus.log")
    load: list[subprocess.Popen] = []
    try:
        group.start()
        first = nodes.push(TAKE_AND_RETURN, iface, node="arm", table_version=1)
        assert first.ok, first.output
        # The node saves at most once a second (Config::store_interval_us): the second save
        # waits for nothing.
        time.sleep(1.0)
        load = [cangen(iface, BOARD_ID, BOARD_BURST), cangen(iface, OTHER_ID, OTHER_BURST)]
        time.sleep(SETTLE_S)
        pushed_at = time.time()
        # SAVES tables, each stored under load (a page erase and two chunks each: the table is
        # 190 bytes); each push returns once its table is stored.
        for version in range(2, 2 + SAVES):
            pushed = nodes.push(TAKE_AND_RETURN, iface, node="arm", table_version=version)
            assert pushed.ok, pushed.output
            nodes.pushed_within_budget(bound, pushed)
        answered_at = time.time()
        time.sleep(SETTLE_S)
        load_end = time.time()
    finally:
        for process in load:
            process.terminate()
            process.wait(timeout=10)
        # Two heartbeat groups after the load: the node's last Traffic and Fault frames.
        time.sleep(0.6)
        group.stop()
        recorder.close()
    arm = group["arm"]
    frames = list(can.CanutilsLogReader(str(out_dir / "bus.log")))
    loaded = [m for m in frames if not m.is_extended_id
              and m.arbitration_id in (BOARD_ID, OTHER_ID)]
    span = loaded[-1].timestamp - loaded[0].timestamp if len(loaded) > 1 else 0.0
    lost = 0
    for m in frames:
        ident = p.FrameId.decode(m.arbitration_id, m.is_extended_id)
        if ident is not None and ident.source == ARM and ident.service == p.FAULT:
            fault = p.Fault.decode(bytes(m.data))
            if fault.code == p.RX_OVERRUN:
                lost = max(lost, fault.frames_lost)
    return {
        "load_frames_per_s": len(loaded) / span if span else 0.0,
        "board_frames": sum(1 for m in loaded if m.arbitration_id == BOARD_ID),
        "frames_lost_by_the_board": lost,
        "line_losses": arm.line_losses(),
        "saves": SAVES,
        "pushes_to_last_applied_s": answered_at - pushed_at,
        "load_s": load_end - pushed_at + SETTLE_S,
    }


def test_a_table_saved_under_load_loses_no_frame_on_the_dual_bank_layout(iface, out_dir, bound,
                                                                          machine, figures):
    found = save_under_load(iface, out_dir, None, bound)
    figures("save-under-load-dual-bank", found)
    # The load the test claims: the rate cangen reached, as the bus recorded it (a loaded machine
    # sends more slowly; the frames to the board during the save are what matter, and they are
    # counted).
    bound("the load on the bus", found["load_frames_per_s"], least=LOAD_FPS / machine.factor,
          unit="frames/s", detail=found)
    assert found["line_losses"] == 0, found
    assert found["frames_lost_by_the_board"] == 0, found


def test_the_same_save_on_the_single_bank_layout_loses_frames(iface, out_dir, bound, machine,
                                                               figures):
    found = save_under_load(iface, out_dir, board.single_bank_firmware(), bound)
    figures("save-under-load-single-bank", found)
    bound("the load on the bus", found["load_frames_per_s"], least=LOAD_FPS / machine.factor,
          unit="frames/s", detail=found)
    assert found["line_losses"] == 0, found
    # Each save's page erase stalls the CPU for 22 ms, in which some six of the board's frames
    # arrive on the bus and three fit the controller's FIFO (fewer reach the emulated board within
    # the stall: its serial line is slower than the bus).
    assert found["frames_lost_by_the_board"] > 0, found
