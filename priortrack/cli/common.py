"""What the ``priortrack`` verbs share: a progress line, JSON output, motions from names."""

from __future__ import annotations

import json
import sys
import time


class Progress:
    """A one-line progress display on stderr: a step count and a value (objective, or total); with
    ``rate``, the value is the total and the line adds steps per second and the time left (ETA) at the
    rate since the first update. Shown only on a terminal: a log file would get every update on one line."""

    def __init__(self, label: str, template: str = "step {0:5d}  objective {1:.6g}", rate: bool = False):
        self.label, self.template, self.rate = label, template, rate
        self.shown = sys.stderr.isatty()
        self.last = None
        self.first: tuple[int, float] | None = None

    def __call__(self, step: int, value: float) -> None:
        if not self.shown:
            return
        self.last = (step, value)
        line = self.template.format(step, value)
        if self.rate:
            now = time.perf_counter()
            self.first = self.first or (step, now)
            if step > self.first[0] and now > self.first[1]:
                per_second = (step - self.first[0]) / (now - self.first[1])
                left = max(value - step, 0) / per_second
                line += f"  {per_second:.1f}/s  ETA {int(left // 60)}:{int(left % 60):02d}"
        print(f"\r{self.label}: " + line + "   ", end="", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.last is not None:
            print(file=sys.stderr)


def print_json(result: dict) -> None:
    print(json.dumps(result, indent=None if not sys.stdout.isatty() else 2))


def load_motions(sources: list[str]):
    from priortrack.data.bundled import expand_sources
    from priortrack.data.load import load_motion

    return [load_motion(source) for source in expand_sources(sources)]

