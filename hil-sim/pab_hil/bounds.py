"""The suite's timing bounds and their margins (written by the tests' `bound` fixture, one JSON
line each, into the results directory's bounds.jsonl): printed after a run, and summed up over
several runs (`python -m pab_hil margins RESULTS...`), so that a margin that shrinks is seen before
the bound fails."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

FILE = "bounds.jsonl"


@dataclass(frozen=True)
class Bound:
    test: str
    name: str
    measured: float
    least: float | None
    most: float | None
    unit: str
    margin: float
    margin_of_limit: float | None

    def describe(self) -> str:
        limits = " and ".join(part for part in (
            None if self.least is None else f">= {self.least:.4g}",
            None if self.most is None else f"<= {self.most:.4g}") if part)
        share = "" if self.margin_of_limit is None else f", {100 * self.margin_of_limit:.0f} % of the limit"
        return (f"{self.name}: {self.measured:.4g} {self.unit} (bound {limits}; margin "
                f"{self.margin:.4g} {self.unit}{share})")


def read(results: Path) -> list[Bound]:
    """The bounds of one run, in the order the tests checked them; none if it wrote none."""
    path = results / FILE
    if not path.exists():
        return []
    return [Bound(**json.loads(line)) for line in path.read_text().splitlines() if line.strip()]


def report(bounds: list[Bound]) -> list[str]:
    """One line per bound, for run-hil's summary."""
    return [f"run-hil: bound {b.test}: {b.describe()}" for b in bounds]


def smallest(runs: list[Path]) -> list[str]:
    """Over several runs' results directories: per bound, how many runs checked it and its
    smallest margin (and where)."""
    best: dict[tuple[str, str], tuple[Bound, Path, int]] = {}
    for run in runs:
        for b in read(run):
            key = (b.test, b.name)
            seen = best.get(key)
            count = 1 + (seen[2] if seen else 0)
            if seen is None or b.margin < seen[0].margin:
                best[key] = (b, run, count)
            else:
                best[key] = (seen[0], seen[1], count)
    return [f"{test}: {b.describe()}; smallest of {count} run(s), in {run}"
            for (test, _), (b, run, count) in best.items()]
