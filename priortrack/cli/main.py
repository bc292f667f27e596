"""The ``priortrack`` command line: the parser, and one error line for bad input.

Each verb family lives in its own module, its parser beside the code it calls: ``data`` (presets,
data list, replay), ``priors`` (fit, sample, plot), ``track``, ``compare``, ``evaluate`` (eval …),
``bench`` (bench …). Bad input ends with one line ``priortrack: error: …`` and exit status 2, never a
traceback; Ctrl-C with ``priortrack: interrupted`` and 130, except inside ``track``'s filter run, which
ends there and writes what it tracked (exit 0, said on stderr and in the JSON summary).
"""

from __future__ import annotations

import argparse
import logging
import sys

from priortrack.cli import bench, compare, data, evaluate, priors, track
from priortrack.errors import PriortrackError

#: The families, in the order ``priortrack --help`` lists their verbs.
FAMILIES = (data, priors, track, compare, evaluate, bench)


def build_parser() -> argparse.ArgumentParser:
    """The command line's parser; it imports nothing heavy (no torch), so ``--help`` and argument
    errors are immediate."""
    parser = argparse.ArgumentParser(
        prog="priortrack", description="Learned motion priors in Bayesian filters: track a 3D body from 2D joints, "
                                       "compare filters, replay why a tracker failed.")
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress (INFO) to stderr")
    verbs = parser.add_subparsers(dest="verb", required=True, metavar="VERB")
    for family in FAMILIES:
        family.add_parsers(verbs)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        args.run(args)
    except (PriortrackError, OSError) as exc:         # OSError: a file that could not be read or written
        print(f"priortrack: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:                         # Ctrl-C outside a run that keeps what it tracked
        print("priortrack: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
