"""``tepinn-flight``: the one console script. Subcommands live in ``cli/<name>_cmd.py``.

Each command module defines ``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``
and keeps heavy imports (torch, jsbsim) inside ``run``. Errors from bad input
(:class:`~tepinn_flight.errors.TepinnError`) become one line on stderr and exit code 2; set
``TEPINN_DEBUG=1`` to see tracebacks.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import os
import sys

from .. import __version__
from ..errors import TepinnError

#: (command, module) in the order ``--help`` lists them; a command shows up once its module exists.
COMMANDS = [
    ("demo", "demo_cmd"),
    ("ingest", "ingest_cmd"),
    ("info", "info_cmd"),
    ("simulate", "simulate_cmd"),
    ("train", "train_cmd"),
    ("estimate", "estimate_cmd"),
    ("evaluate", "evaluate_cmd"),
    ("ablate", "ablate_cmd"),
    ("benchmark", "benchmark_cmd"),
    ("replay", "replay_cmd"),
    ("bridge", "bridge_cmd"),
]


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse's usage errors: one line, exit 2
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        sys.exit(2)


def available_commands() -> list[tuple[str, str]]:
    return [(c, m) for c, m in COMMANDS if importlib.util.find_spec(f"{__package__}.{m}") is not None]


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="tepinn-flight",
        description="Attitude estimation for drones and aircraft with TE-PINN, checked against the autopilot.",
    )
    parser.add_argument("--version", action="version", version=f"tepinn-flight {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, module in available_commands():
        mod = importlib.import_module(f"{__package__}.{module}")
        p = sub.add_parser(name, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP))
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    debug = os.environ.get("TEPINN_DEBUG") not in (None, "", "0")
    try:
        return int(args._run(args) or 0)
    except TepinnError as exc:
        if debug:
            raise
        sys.stderr.write(f"tepinn-flight {args.command}: error: {exc}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write(f"tepinn-flight {args.command}: interrupted\n")
        return 130
    except BrokenPipeError:  # output piped into `head` and closed: not an error of ours
        try:
            sys.stdout = open(os.devnull, "w")
        except OSError:
            pass
        return 141
    except Exception as exc:  # a bug, not bad input: still one line unless debugging
        if debug:
            raise
        first = (str(exc).strip().splitlines() or [""])[0]
        sys.stderr.write(
            f"tepinn-flight {args.command}: internal error: {type(exc).__name__}: {first} "
            "(set TEPINN_DEBUG=1 for the traceback)\n"
        )
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
