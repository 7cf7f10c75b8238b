"""A HIL capture against `pabctl check`'s worst-case response times: `pabctl replay --timed-bus`.

On `vcan` a frame takes no bus time, so the latencies the suite could time there are the nodes'
processing and the host's scheduling, not a bus's response time. What the capture does hold is
when each real process sent each frame: the behaviours' frames with their scheduling jitter, the
nodes' heartbeat groups, gateways and answers, the tool's pushes. `pabctl replay --timed-bus`
queues every frame at its timestamp on a bus that takes each frame's actual bits at the network's
bit rate, and compares each analysed stream's latencies with its bound R.

The network it compares against is the one the suite runs, as the suite runs it: the nodes beat
every `HEARTBEAT_MS` (`pab-node --heartbeat-ms`, so `heartbeat` on each node), and the behaviours
are Python processes that wake up to `PUBLISHER_JITTER_S` late (`jitter` on each periodic topic).
A frame that comes sooner after its stream's earlier frames than that allows is outside the
analysis: the replay reports it and does not compare it; the others must all be within R."""

from __future__ import annotations

import json
import re
import subprocess
import tomllib
from dataclasses import dataclass
from pathlib import Path

from .nodes import HEARTBEAT_MS, binary

# How late a behaviour process may wake for its period, as declared to the analysis. A later
# frame is reported (beyond its period) and not compared, so this bounds what is compared, not
# whether the check passes.
PUBLISHER_JITTER_S = 0.02


def as_run(network: Path, directory: Path) -> Path:
    """`network` as the suite runs it: `heartbeat` on each node, `jitter` on each topic with a
    period (where it has none). Written beside the test's other outputs."""
    text = network.read_text()
    parsed = tomllib.loads(text)
    lines = []
    for line in text.splitlines():
        lines.append(line)
        header = re.match(r"\s*\[nodes\.([A-Za-z0-9_]+)\]", line)
        if header and header.group(1) in parsed.get("nodes", {}):
            lines.append(f"heartbeat = {HEARTBEAT_MS / 1000}")
    text = "\n".join(lines) + "\n"
    for name, topic in parsed.get("topics", {}).items():
        if ("period" in topic or "rate_hz" in topic) and "jitter" not in topic:
            header = re.compile(rf"^\[topics\.{re.escape(name)}\][^\n]*$", re.MULTILINE)
            text = header.sub(lambda m: f"{m.group(0)}\njitter = {PUBLISHER_JITTER_S}", text, 1)
    path = directory / f"{network.stem}-as-run.toml"
    path.write_text(text)
    return path


@dataclass(frozen=True)
class TimedReplay:
    """What `pabctl replay --timed-bus --json` said of a capture."""

    returncode: int
    output: str  # its text (standard error), for a failing assertion
    timed_bus: dict  # the JSON's `timed_bus` (docs/pabctl.md, "JSON output")

    def streams_with_frames(self) -> list[dict]:
        return [s for s in self.timed_bus["streams"] if s["frames"]]

    def figure(self) -> dict:
        """Streams and frames compared, and the compared latency closest to its bound."""
        compared = [s for s in self.timed_bus["streams"] if s["compared"]]
        closest = max(compared, key=lambda s: s["worst_latency_s"] / s["bound_s"])
        return {
            "carried": self.timed_bus["carried"],
            "streams_compared": len(compared),
            "frames_compared": sum(s["compared"] for s in compared),
            "frames_of_analysed_streams": sum(s["frames"] for s in self.timed_bus["streams"]),
            "closest": closest["name"],
            "closest_latency_ms": round(closest["worst_latency_s"] * 1000, 3),
            "closest_bound_ms": round(closest["bound_s"] * 1000, 3),
        }


def timed_replay(network: Path, log: Path, directory: Path) -> TimedReplay:
    """`pabctl replay NETWORK LOG --timed-bus --json`, NETWORK as the suite runs it."""
    as_run_path = as_run(network, directory)
    result = subprocess.run(
        [str(binary("pabctl")), "replay", str(as_run_path), str(log), "--timed-bus", "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, timeout=300)
    (directory / "timed-bus.txt").write_text(result.stderr)
    found = json.loads(result.stdout) if result.stdout.strip() else {}
    return TimedReplay(result.returncode, result.stderr, found.get("timed_bus", {}))
