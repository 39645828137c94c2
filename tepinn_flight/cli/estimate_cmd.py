"""``tepinn-flight estimate [--model CKPT|MODEL.onnx] [--runtime torch|onnx|auto] RECORD... -o OUT``."""

from __future__ import annotations

from .argtypes import threads

HELP = "estimate attitude over flight records with TE-PINN (the shipped model by default)"
DESCRIPTION = (
    "Runs causally over whole records (batched sliding windows, then RK4 propagation fused with the "
    "window estimates) and writes one row per input row: t_s, q_est_w..z (body->NED), sigma_rad, "
    "gyr_bias_est_*_rad_s; NaN until the first window of a segment is full."
)


def add_arguments(p) -> None:
    p.add_argument("records", nargs="+", metavar="RECORD", help="flight records (.parquet; use `ingest` for raw logs)")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="output file (one record) or folder")
    p.add_argument("--model", default=None, metavar="CKPT",
                   help="checkpoint or .onnx export (`tepinn-flight export`; default: the shipped model)")
    p.add_argument("--runtime", choices=["auto", "torch", "onnx"], default="auto",
                   help="run the network in PyTorch or onnxruntime (auto: onnx for an .onnx model or where torch is "
                        "not installed, else torch)")
    p.add_argument("--yaw", choices=["gyro", "zero"], default=None,
                   help="heading of the output: integrated gyro (default) or 0 (the paper's 6-D correction)")
    p.add_argument("--threads", type=threads, default=0, help="CPU threads of the runtime (default: its own choice)")
    p.add_argument("-q", "--quiet", action="store_true")


def run(args) -> int:
    import dataclasses
    import sys
    from pathlib import Path

    import pyarrow as pa
    import pyarrow.parquet as pq

    from ..errors import TepinnError
    from ..model.checkpoint import default_model_path
    from ..model.estimate import estimate_record
    from ..model.runtime import default_onnx_path, load_runner, resolve_runtime
    from ..record import atomic_write, check_output, read_record
    from .ingest_cmd import output_paths

    ckpt_path = Path(args.model) if args.model else default_model_path()
    if not args.model and resolve_runtime(ckpt_path, args.runtime) == "onnx" and default_onnx_path().is_file():
        ckpt_path = default_onnx_path()  # the shipped model, exported
    if not args.model and not ckpt_path.exists():
        raise TepinnError("the shipped default model is missing from this installation; pass --model CKPT")
    model, fusion, _ = load_runner(ckpt_path, args.runtime, args.threads or None)
    if args.yaw and hasattr(fusion, "yaw"):  # the network-centred fusion only (the anchored one has VQF's heading)
        fusion = dataclasses.replace(fusion, yaw=args.yaw)
    paths = [Path(p) for p in args.records]
    outs = output_paths(paths, args.output)
    for dst in outs:  # before any work: an output that cannot be written is a one-line error
        check_output(dst)
    failures = 0
    from tqdm import tqdm

    for src, dst in tqdm(list(zip(paths, outs)), unit="record", file=sys.stderr, disable=args.quiet or len(paths) < 2):
        try:
            rec = read_record(src)
            if not rec.meta.get("estimation_ok", True):
                rate = rec.meta.get("imu_rate_hz")
                sys.stderr.write(f"tepinn-flight estimate: warning: {src}: IMU "
                                 f"{'rate unknown' if rate is None else f'at {rate:.1f} Hz'} is too slow for windowed "
                                 "estimation (estimation_ok is false); estimating anyway, expect poor attitude\n")  # fmt: skip
            df = estimate_record(model, rec, fusion)
        except TepinnError as exc:
            failures += 1
            sys.stderr.write(f"tepinn-flight estimate: error: {exc if exc.path else f'{src}: {exc}'}\n")
            continue
        table = pa.Table.from_pandas(df, preserve_index=False)
        table = table.replace_schema_metadata({b"source_record": str(src.name).encode(), b"model": str(ckpt_path.name).encode()})
        atomic_write(dst, lambda tmp: pq.write_table(table, tmp))
        if not args.quiet:
            ok = df["q_est_w"].notna().mean()
            print(f"{src} -> {dst}: {len(df)} rows, {100 * ok:.1f}% estimated")
    return 2 if failures else 0
