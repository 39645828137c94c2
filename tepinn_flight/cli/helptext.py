"""Shared ``--help`` layout for the verbs: the description wrapped as argparse would, then an
``examples:`` section with one command per line (argparse would run them together)."""

from __future__ import annotations

import argparse
import shutil
import textwrap


def add_examples(p: argparse.ArgumentParser, *examples: str) -> None:
    """Give ``p`` an ``examples:`` epilog (one ``tepinn-flight ...`` command per line, a ``# comment``
    after two spaces allowed) while its description stays wrapped to the terminal."""
    width = max(40, min(shutil.get_terminal_size().columns, 120) - 2)
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    if p.description:
        p.description = "\n\n".join(textwrap.fill(" ".join(par.split()), width) for par in p.description.split("\n\n"))
    p.epilog = "examples:\n" + "\n".join(f"  {e}" for e in examples)
