"""What the ``priortrack`` verbs share: a progress line, JSON output, motions from names."""

from __future__ import annotations

import json
import sys


class Progress:
    """A one-line progress display on stderr: a step count and a value (objective, or total).
    Shown only on a terminal: a log file would get every update on one line."""

    def __init__(self, label: str, template: str = "step {0:5d}  objective {1:.6g}"):
        self.label, self.template = label, template
        self.shown = sys.stderr.isatty()
        self.last = None

    def __call__(self, step: int, value: float) -> None:
        if not self.shown:
            return
        self.last = (step, value)
        print(f"\r{self.label}: " + self.template.format(step, value), end="", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.last is not None:
            print(file=sys.stderr)


def print_json(result: dict) -> None:
    print(json.dumps(result, indent=None if not sys.stdout.isatty() else 2))


def load_motions(sources: list[str]):
    from priortrack.data.bundled import expand_sources
    from priortrack.data.load import load_motion

    return [load_motion(source) for source in expand_sources(sources)]

