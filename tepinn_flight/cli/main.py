"""``tepinn-flight``: the one console script. Subcommands live in ``cli/<name>_cmd.py``.

Each command module defines ``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``
and keeps heavy imports (torch, jsbsim) inside ``run``. Errors from bad input
(:class:`~tepinn_flight.errors.TepinnError`) become one line on stderr and exit code 2; set
``TEPINN_DEBUG=1`` to see tracebacks.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from .. import __version__
from ..errors import TepinnError
from ..worker_processes import Terminated, terminate_on_sigterm

#: (command, module) in the order ``--help`` lists them. Every one is always listed: a module that
#: fails to import leaves its command in place, marked BROKEN, and the command (its ``--help`` too)
#: fails with exit code 1 (see :func:`build_parser`). tests/test_cli.py checks this list against
#: the ``cli/*_cmd.py`` files.
COMMANDS = [
    ("demo", "demo_cmd"),
    ("ingest", "ingest_cmd"),
    ("info", "info_cmd"),
    ("simulate", "simulate_cmd"),
    ("train", "train_cmd"),
    ("estimate", "estimate_cmd"),
    ("export", "export_cmd"),
    ("evaluate", "evaluate_cmd"),
    ("ablate", "ablate_cmd"),
    ("benchmark", "benchmark_cmd"),
    ("replay", "replay_cmd"),
    ("bridge", "bridge_cmd"),
]


class _Parser(argparse.ArgumentParser):
    """No abbreviated options (``--mode`` must not be taken for ``--model``); usage errors in one line.

    Nested sub-parsers (``add_subparsers`` without ``parser_class``) are of this class too."""

    def __init__(self, *args, allow_abbrev: bool = False, **kwargs):
        super().__init__(*args, allow_abbrev=allow_abbrev, **kwargs)

    def error(self, message):  # argparse's usage errors: one line, exit 2
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        sys.exit(2)


#: command -> "ExcType: message" for command modules that failed to import in :func:`build_parser`.
UNAVAILABLE: dict[str, str] = {}


def _unavailable_message(name: str, reason: str) -> str:
    module = dict(COMMANDS).get(name, name)
    return (f"internal error: the command's module cli/{module}.py failed to import ({reason}); "
            "set TEPINN_DEBUG=1 for the traceback")


def build_parser() -> argparse.ArgumentParser:
    """The parser with every command of :data:`COMMANDS`.

    A command module that fails to import (a bug or a broken installation, never bad input: the
    modules keep their heavy imports inside ``run``) stays listed as BROKEN, and :func:`main` fails
    that command, ``--help`` included, with the reason and exit code 1; with ``TEPINN_DEBUG=1`` the
    import error is raised instead."""
    parser = _Parser(
        prog="tepinn-flight",
        description="Attitude estimation for drones and aircraft with TE-PINN, checked against the autopilot.",
    )
    parser.add_argument("--version", action="version", version=f"tepinn-flight {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    UNAVAILABLE.clear()
    for name, module in COMMANDS:
        try:
            mod = importlib.import_module(f"{__package__}.{module}")
        except Exception as exc:
            if os.environ.get("TEPINN_DEBUG") not in (None, "", "0"):
                raise
            first = (str(exc).strip().splitlines() or [""])[0]
            reason = f"{type(exc).__name__}: {first}"
            UNAVAILABLE[name] = reason
            sub.add_parser(name, help=f"BROKEN ({reason})", add_help=False)
            continue
        p = sub.add_parser(name, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP))
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def command_names(parser: argparse.ArgumentParser) -> list[str]:
    """The commands ``parser`` (from :func:`build_parser`) accepts, in order."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return list(action.choices)
    return []


def main(argv: list[str] | None = None) -> int:
    """The console script. A Ctrl-C or SIGTERM while the commands' modules are still importing (the first half second:
    numpy) ends in one line and 130 / 143 too (review59: a traceback, and SIGTERM killed it without a word)."""
    try:
        with terminate_on_sigterm():
            return _main(argv)
    except Terminated:
        sys.stderr.write("tepinn-flight: terminated\n")
        return 143
    except KeyboardInterrupt:
        sys.stderr.write("tepinn-flight: interrupted\n")
        return 130


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and argv[0] in UNAVAILABLE:  # whatever its arguments, --help too: loud, not a usage text
        sys.stderr.write(f"tepinn-flight {argv[0]}: {_unavailable_message(argv[0], UNAVAILABLE[argv[0]])}\n")
        return 1
    args = parser.parse_args(argv)
    model = getattr(args, "model", None)  # "--model default" names the shipped model, as "train --init default" does
    if model == "default" and not os.path.exists("default"):
        args.model = None
    elif isinstance(model, list) and "default" in model and not os.path.exists("default"):  # (evaluate, benchmark)
        from ..model.checkpoint import default_model_path

        args.model = [str(default_model_path()) if m == "default" else m for m in model]
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    for flag in ("output", "tlog", "summary_json", "json"):  # an empty -o (a shell variable never set) is no output
        if getattr(args, flag, None) == "":
            name = {"output": "-o", "summary_json": "--summary-json"}.get(flag, f"--{flag}")
            sys.stderr.write(f"tepinn-flight {args.command}: error: {name} is empty: name an output\n")
            return 2
    debug = os.environ.get("TEPINN_DEBUG") not in (None, "", "0")
    try:
        with terminate_on_sigterm():  # SIGTERM (timeout, systemd, a scheduler) cleans up as Ctrl-C does
            return int(args._run(args) or 0)
    except TepinnError as exc:
        if debug:
            raise
        sys.stderr.write(f"tepinn-flight {args.command}: error: {exc}\n")
        return 2
    except Terminated:
        sys.stderr.write(f"tepinn-flight {args.command}: terminated\n")
        return 143
    except KeyboardInterrupt:
        sys.stderr.write(f"tepinn-flight {args.command}: interrupted\n")
        return 130
    except ModuleNotFoundError as exc:
        from ..model.runtime import TORCH_MODULES

        if exc.name in TORCH_MODULES and not debug:  # a torch-less install (the [runtime] extra): a verb that needs
            # torch says so in one line (review60: "internal error", exit 1)
            sys.stderr.write(f"tepinn-flight {args.command}: error: this needs PyTorch, which this install does not have "
                             f"(No module named {exc.name!r}): pip install 'tepinn-flight[torch]' — estimate, bridge, "
                             "replay and info run without it on an ONNX export\n")  # fmt: skip
            return 2
        return _internal_error(args.command, exc, debug)
    except BrokenPipeError:  # output piped into `head` and closed: not an error of ours
        try:
            sys.stdout = open(os.devnull, "w")
        except OSError:
            pass
        return 141
    except Exception as exc:  # a bug, not bad input: still one line unless debugging
        return _internal_error(args.command, exc, debug)


def _internal_error(command: str, exc: BaseException, debug: bool) -> int:
    """A bug, not bad input: one line and exit 1 (raised again where debugging)."""
    if debug:
        raise exc
    first = (str(exc).strip().splitlines() or [""])[0]
    sys.stderr.write(f"tepinn-flight {command}: internal error: {type(exc).__name__}: {first} "
                     "(set TEPINN_DEBUG=1 for the traceback)\n")  # fmt: skip
    return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
