"""The torch-less environment the runtime extra makes (``pip install ".[runtime]"`` into a plain venv), built once per
test session: by the session's warm-up beside the cold numba compile where this checkout's cache was empty (CI's
clean clone, ``tests/conftest.py``: a worker otherwise idle there), else by ``tests/test_onnx_runtime.py``'s fresh-venv
test itself."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def index_reachable(tmp: Path) -> str | None:
    """None when pip can fetch packages, else why not."""
    p = subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "-d", str(tmp / "dl"), "-q", "tqdm"],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    return None if p.returncode == 0 else (p.stderr.strip().splitlines() or ["pip download failed"])[-1]


def build_runtime_venv(folder: Path) -> dict:
    """A plain venv in ``folder``/venv with this checkout's ``[runtime]`` extra installed → {"skip": why pip cannot
    reach the package index or None, "venv": its path, "returncode", "stderr": pip's}."""
    folder.mkdir(parents=True, exist_ok=True)
    why = index_reachable(folder)
    if why:
        return {"skip": why, "venv": None, "returncode": None, "stderr": ""}
    venv = folder / "venv"
    # a plain venv without pip of its own: this pip installs into it (--python; seeding the venv's own pip was ~5 s of
    # CI's time)
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    src = folder / "src"  # a copy: the build must not leave files in the checkout
    shutil.copytree(REPO, src, ignore=shutil.ignore_patterns(".git", ".venv", "__pycache__", "*.egg-info", "build", "tests",
                                                           "runs"))  # fmt: skip
    # --no-compile: the installed packages' byte-code is written as they are first imported, not all up front (pip's
    # compiling of ~1 GB of packages was half of this install: 76 -> 31 s)
    p = subprocess.run([sys.executable, "-m", "pip", "--python", str(venv / "bin" / "python"), "install", "-q",
                        "--no-compile", f"{src}[runtime]"], capture_output=True, text=True, timeout=600)  # fmt: skip
    return {"skip": None, "venv": str(venv), "returncode": p.returncode, "stderr": p.stderr[-3000:]}
