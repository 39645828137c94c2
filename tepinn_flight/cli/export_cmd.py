"""``tepinn-flight export [MODEL] -o model.onnx``: a checkpoint as ONNX, for onnxruntime without torch."""

from __future__ import annotations

from .helptext import add_examples

HELP = "export a TE-PINN checkpoint (the shipped model by default) to ONNX for onnxruntime (no torch needed to run it)"
DESCRIPTION = (
    "Writes the network as an ONNX graph (export version 3, opset 17, float32): the network from its token "
    "features to its heads' linear layers (inputs x, t_rel, with a dynamic batch axis and the window length fixed "
    "by the model config; outputs q_head, pool, sigma, bias, vel, acc_v), with the checkpoint's model_config, "
    "anchor_config/fusion_config, conventions and trained sensor model (sensor_model) as JSON in its metadata; "
    "tepinn-flight's runtime computes the features from the windows and the attitude from the heads' outputs "
    "(compiled). Exports of versions 1 and 2 still run. "
    "`estimate --model MODEL.onnx` and `bridge --model MODEL.onnx` run it with onnxruntime. Needs torch and onnx."
)


def add_arguments(p) -> None:
    add_examples(p,
                 'tepinn-flight export -o tepinn.onnx                # the shipped model',
                 'tepinn-flight export runs/mine/model.pt -o mine.onnx')
    p.add_argument("model", nargs="?", default=None, metavar="MODEL", help="checkpoint (default: the shipped model)")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="the .onnx file to write")
    p.add_argument("--opset", type=int, default=None, metavar="N", help="ONNX opset (default 17)")
    p.add_argument("--no-check", action="store_true", help="skip comparing onnxruntime with torch on random windows")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")


def run(args) -> int:
    from pathlib import Path

    from ..errors import ConfigError, TepinnError
    from ..model.checkpoint import default_model_path
    from ..model.runtime import is_onnx_path

    src = Path(args.model) if args.model else default_model_path()
    if not src.is_file():
        raise TepinnError(f"{src}: no such checkpoint")
    out = Path(args.output)
    if not is_onnx_path(out):
        raise ConfigError(f"-o {out}: the output must end in .onnx")
    if not out.parent.is_dir():
        what = "is a file, not a folder" if out.parent.exists() else "does not exist"
        raise ConfigError(f"-o {out}: folder {out.parent} {what}")
    from .paths import refuse_overwriting_inputs

    refuse_overwriting_inputs([("-o", out)], [src])  # (a link named .onnx to the checkpoint had replaced it)
    try:
        import onnx  # noqa: F401
        import torch  # noqa: F401
    except ImportError as exc:
        raise TepinnError(f"export needs torch and onnx ({exc}); pip install 'tepinn-flight[torch]'") from None
    from ..model.export import OPSET, check_export, export_onnx

    if args.opset is not None and args.opset < 1:
        raise ConfigError(f"--opset {args.opset}: an ONNX opset is a positive number (default {OPSET})")
    opset = OPSET if args.opset is None else args.opset
    try:  # torch's own range: outside it its exporter prints a page of graph before it fails (session 57)
        from torch.onnx import _constants as onnx_range

        lo, hi = int(onnx_range.ONNX_MIN_OPSET), int(onnx_range.ONNX_MAX_OPSET)
    except (ImportError, AttributeError):
        lo = hi = None
    if lo is not None and not lo <= opset <= hi:
        raise ConfigError(f"--opset {opset}: this torch exports opsets {lo}–{hi} (default {OPSET}, the one tested)")
    try:
        with _native_output_held() as held:  # (torch prints the whole graph from C++ before an opset failure)
            export_onnx(src, out, opset)
        held.replay()  # exported: whatever it printed is shown
    except Exception as exc:  # noqa: BLE001 - torch's exporter raises several types for an opset it cannot write
        if opset == OPSET:
            held.replay()
            raise  # the tested opset failing is a bug: an internal error
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:160]
        raise TepinnError(f"--opset {opset}: torch cannot export the network at this opset ({first}); "
                          f"{OPSET} is the one tested") from None  # fmt: skip
    msg = f"{src} -> {out}: opset {opset}, {out.stat().st_size / 1024:.0f} KiB"
    if not args.no_check:
        err = check_export(src, out)
        msg += f"; onnxruntime vs torch max |diff| {err:.1e}"
        if err > 1e-4:
            raise TepinnError(f"{out}: onnxruntime differs from torch by {err:.1e} (> 1e-4)")
    if not args.quiet:
        print(msg)
    return 0


class _native_output_held:
    """Hold what native code writes to file descriptors 1 and 2 (Python's own ``print`` too) until the caller decides
    (:meth:`replay` shows it): torch's ONNX exporter dumps its whole graph there, 176 lines, before it fails at an
    opset it cannot write."""

    def __enter__(self) -> "_native_output_held":
        import os
        import sys
        import tempfile

        self.out = self.err = b""
        sys.stdout.flush()
        sys.stderr.flush()
        self.files = [tempfile.TemporaryFile() for _ in range(2)]
        self.saved = [os.dup(1), os.dup(2)]
        for fd, f in zip((1, 2), self.files):
            os.dup2(f.fileno(), fd)
        return self

    def __exit__(self, *exc) -> bool:
        import os
        import sys

        sys.stdout.flush()
        sys.stderr.flush()
        for fd, saved in zip((1, 2), self.saved):
            os.dup2(saved, fd)
            os.close(saved)
        for f in self.files:
            f.seek(0)
        self.out, self.err = (f.read() for f in self.files)
        for f in self.files:
            f.close()
        return False

    def replay(self) -> None:
        import sys

        for data, stream in ((self.out, sys.stdout), (self.err, sys.stderr)):
            if data:
                stream.flush()
                stream.buffer.write(data) if hasattr(stream, "buffer") else stream.write(data.decode(errors="replace"))
                stream.flush()
