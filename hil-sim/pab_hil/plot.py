"""The stimulation plot of a session, drawn from the nodes' diagnostic stream (Figure 5 style).

One panel per node: each connection's stimulation S over time, marked green while the node's
decision selects it (delivering), and a strip of the phases the world went through.
The values are the nodes' own, as they sent them on the bus.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from . import observe  # noqa: E402
from .nodes import NODE_IDS  # noqa: E402

COLOURS = ["#1f77b4", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"]
PHASE_COLOURS = {"A": "#dfe7f2", "B": "#f6e3c6", "C": "#f3cfcf", "D": "#d9ead3",
                 "E": "#e6d9f0", "F": "#fff2b3", "-": "#ffffff"}


def connection_names(network: Path) -> dict[tuple[str, int, int], str]:
    """(node name, port index, connection index) -> connection name, in the file's order (the
    order the compiler numbers them in)."""
    doc = tomllib.loads(network.read_text())
    ports_of: dict[str, list[str]] = {}
    for port in doc.get("ports", {}):
        node = port.split(".", 1)[0]
        ports_of.setdefault(node, []).append(port)
    names = {}
    for node, ports in ports_of.items():
        for port_index, port in enumerate(ports):
            members = [c for c, spec in doc.get("connections", {}).items() if spec.get("port") == port]
            for index, connection in enumerate(members):
                names[(node, port_index, index)] = f"{connection} ({doc['connections'][connection]['topic']})"
    return names


def plot_session(session, path: Path, title: str) -> None:
    names = connection_names(session.network)
    changes = session.phases.changes()
    end = session.world.now()
    fig, axes = plt.subplots(len(NODE_IDS) + 1, 1, figsize=(13, 10), sharex=True,
                             gridspec_kw={"height_ratios": [3] * len(NODE_IDS) + [0.6]})
    every = observe.samples(session.log_path, session.world.epoch)
    if every:  # the run's end, not the (later) moment of drawing
        end = max(s.time for s in every)
    for ax, (node, node_id) in zip(axes, NODE_IDS.items()):
        samples = [s for s in every if s.node == node_id]
        series: dict[tuple[int, int], list] = {}
        for s in samples:
            series.setdefault((s.sample.port, s.sample.connection), []).append(s)
        for colour, key in zip(COLOURS, sorted(series)):
            points = series[key]
            label = names.get((node, *key), f"port {key[0]} connection {key[1]}")
            ax.plot([p.time for p in points], [p.sample.level for p in points], color=colour,
                    linewidth=1.0, label=label)
        # Delivering on top of every line: the connection the node's decision selects.
        chosen = [s for s in samples if s.sample.delivering]
        ax.scatter([s.time for s in chosen], [s.sample.level for s in chosen], s=9,
                   color="#2ca02c", zorder=3, label="delivering")
        ax.legend(loc="center left", bbox_to_anchor=(1.0, 0.5), fontsize=7, frameon=False)
        ax.set_ylabel(f"{node}\nS")
        ax.set_ylim(-0.02, 1.05)
        ax.grid(alpha=0.3)
    strip = axes[-1]
    for current, following in zip(changes, changes[1:] + [None]):
        stop = following.time if following else end
        if stop <= current.time:
            continue
        strip.axvspan(current.time, stop, color=PHASE_COLOURS.get(current.phase, "#fff"))
        if current.phase != "-" and stop - current.time > 0.3:
            strip.text((current.time + stop) / 2, 0.5, current.phase, ha="center", va="center")
    strip.set_yticks([])
    strip.set_xlabel("time since the behaviours started (s)")
    axes[0].set_title(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


ROBOT_COLOURS = {1: "#1f77b4", 2: "#ff7f0e", 3: "#2ca02c"}


def plot_team(drives, scenes: dict[str, tuple[float, float]], origin: float, path: Path,
              title: str) -> None:
    """Multi-target observation as the bus showed it: one lane per target, a bar per robot while
    its base controller delivered that target's observer (several bars in a lane: shared), and
    the scenes of the run shaded behind."""
    targets = sorted({d.target for d in drives if d.target})
    robots = sorted({d.robot for d in drives})
    fig, ax = plt.subplots(figsize=(13, 1.2 + 0.8 * len(targets)))
    for lane, target in enumerate(targets):
        for slot, robot in enumerate(robots):
            spans = [(d.start - origin, d.end - d.start) for d in drives
                     if d.target == target and d.robot == robot]
            ax.broken_barh(spans, (lane + slot * 0.28 + 0.08, 0.24),
                           color=ROBOT_COLOURS.get(robot, "#7f7f7f"),
                           label=f"r{robot}" if lane == 0 else None)
    for index, (name, (start, end)) in enumerate(scenes.items()):
        ax.axvspan(start - origin, end - origin, color="#eeeeee" if index % 2 else "#f8f8f8",
                   zorder=0)
        ax.text((start + end) / 2 - origin, len(targets) + 0.1, name, ha="center", fontsize=8)
    ax.set_yticks([lane + 0.5 for lane in range(len(targets))])
    ax.set_yticklabels([f"target {t}" for t in targets])
    ax.set_ylim(0, len(targets) + 0.5)
    ax.set_xlabel("time (s)")
    ax.legend(loc="center left", bbox_to_anchor=(1.0, 0.5), frameon=False)
    ax.set_title(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
