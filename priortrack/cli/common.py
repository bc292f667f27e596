"""What the ``priortrack`` verbs share: a progress line, JSON output, motions from names, a camera map."""

from __future__ import annotations

import json
import sys
import time


class Progress:
    """A progress display on stderr: a step count and a value (objective, or total); with ``rate``, the value is the
    total and the line adds steps per second and the time left (ETA) at the rate since the first update. On a
    terminal one line rewritten in place; elsewhere (a log file, nohup, a notebook's ``!``) a line every
    :data:`INTERVAL_S` seconds and the last one at the end."""

    #: Seconds between two progress lines off a terminal.
    INTERVAL_S = 10.0

    def __init__(self, label: str, template: str = "step {0:5d}  objective {1:.6g}", rate: bool = False):
        self.label, self.template, self.rate = label, template, rate
        self.shown = sys.stderr.isatty()
        self.last = None
        self.first: tuple[int, float] | None = None
        self.written: tuple[float, str] | None = None          # off a terminal: when the last line went, and it
        self.line = ""

    def __call__(self, step: int, value: float) -> None:
        self.last = (step, value)
        line = self.template.format(step, value)
        now = time.perf_counter()
        if self.rate:
            self.first = self.first or (step, now)
            if step > self.first[0] and now > self.first[1]:
                per_second = (step - self.first[0]) / (now - self.first[1])
                left = max(value - step, 0) / per_second
                line += f"  {per_second:.1f}/s  ETA {int(left // 60)}:{int(left % 60):02d}"
        if self.shown:
            print(f"\r{self.label}: " + line + "   ", end="", file=sys.stderr, flush=True)
        elif self.written is None or now - self.written[0] >= self.INTERVAL_S:
            print(f"{self.label}: {line}", file=sys.stderr, flush=True)
            self.written = (now, line)
        self.line = line

    def close(self) -> None:
        if self.last is None:
            return
        if self.shown:
            print(file=sys.stderr)
        elif self.written is None or self.written[1] != self.line:
            print(f"{self.label}: {self.line}", file=sys.stderr, flush=True)


def print_json(result: dict) -> None:
    print(json.dumps(result, indent=None if not sys.stdout.isatty() else 2))


def load_motions(sources: list[str]):
    from priortrack.data.bundled import expand_sources
    from priortrack.data.load import load_motion

    return [load_motion(source) for source in expand_sources(sources)]


def add_height_options(parser) -> None:
    """``--height`` and ``--floor``: a one-camera person's size, given or measured from the floor."""
    parser.add_argument("--height", type=float,
                        help="the person's standing height, metres (one camera: the body's size and depth; default: "
                             "measured from the floor, else 1.7)")
    parser.add_argument("--floor",
                        help="one camera: where the floor is along the calibration's up, metres (default 0: its "
                             "origin on the floor), or none (not known: the height is --height or 1.7)")


def floor_level(text: str | None) -> float | None:
    """``--floor`` as metres along up: 0 where not given, None for ``none``; a PriortrackError for anything else."""
    from priortrack.errors import PriortrackError

    if text is None:
        return 0.0
    if text.strip().lower() == "none":
        return None
    try:
        return float(text)
    except ValueError:
        raise PriortrackError(f"--floor must be metres along up or none, got {text!r}") from None


def camera_map(text: str | None) -> dict[str, str] | None:
    """``--camera-map FOLDER=CAMERA,…`` as {detection camera: calibration camera}; None where not given."""
    from priortrack.errors import PriortrackError

    if not text:
        return None
    pairs = [item.split("=", 1) for item in text.split(",")]
    if any(len(p) != 2 or not p[0] or not p[1] for p in pairs):
        raise PriortrackError(f"--camera-map must be FOLDER=CAMERA,…, got {text!r}")
    return dict(pairs)
