"""``tepinn-flight bridge --master ENDPOINT --out ENDPOINT ...``: live TE-PINN next to the autopilot."""

from __future__ import annotations

from ..live.messages import DEFAULT_ESTIMATE_AS, ESTIMATE_AS
from .argtypes import add_runtime, busy_stride
from .helptext import add_examples

HELP = "live MAVLink bridge: route autopilot <-> ground stations and add TE-PINN attitude estimates"
DESCRIPTION = (
    "A transparent MAVLink router (every autopilot message reaches every --out unchanged, every ground "
    "station message reaches the autopilot unchanged) that runs TE-PINN on the autopilot's IMU stream "
    "(HIGHRES_IMU, or ArduPilot's RAW_IMU / SCALED_IMU) and sends, as component 191 of the autopilot's "
    "system: HEARTBEAT (onboard controller, 1 Hz), the estimate stamped with the IMU sample's time_boot_ms "
    "(--rate, default 50 Hz; as NAMED_VALUE_FLOAT tp_roll/tp_pitch/tp_yaw by default, see --estimate-as), and NAMED_VALUE_FLOAT "
    "(tp_dincl, tp_sigma, tp_lat_ms, tp_imu_hz) / DEBUG_VECT (TP_RPY, TP_DIFF, TP_BIAS) diagnostics "
    "comparing it with the autopilot's EKF (see them in the ground station's MAVLink inspector). "
    "Stops on Ctrl-C, SIGTERM or --duration and prints a summary."
)


def add_arguments(p) -> None:
    add_examples(p,
                 'tepinn-flight bridge --master udpin:0.0.0.0:14550 --out udpout:127.0.0.1:14551',
                 'tepinn-flight bridge --master /dev/ttyACM0,115200 --out udpout:127.0.0.1:14551 --tlog session.tlog',
                 'tepinn-flight replay flight.tlog --to udpout:127.0.0.1:14550 &   # then the bridge above: a bench test')
    p.add_argument("--master", required=True, metavar="ENDPOINT",
                   help="the autopilot: udpin:0.0.0.0:14550, tcp:HOST:PORT, tcpin:, udpout: or a serial port /dev/ttyACM0,115200")
    p.add_argument("--out", action="append", default=[], metavar="ENDPOINT",
                   help="a ground station or router, e.g. udpout:127.0.0.1:14551 (repeatable)")
    p.add_argument("--model", default=None, metavar="CKPT", help="checkpoint or .onnx export (default: the shipped model)")
    p.add_argument("--mode", choices=["6d", "9d", "auto"], default="",
                   help="6d, 9d (heading from the magnetometer: magnetic north) or auto (9-D when the vehicle sends "
                        "magnetometer data); default: the model's own (6d for the shipped model)")
    p.add_argument("--busy-stride", type=busy_stride, default=0, metavar="N",
                   help="where the network stays busy (fixed wing), run every N-th window after the first 10 s "
                        "(windows holding a saturated sample always run): less CPU, some accuracy (estimate "
                        "--busy-stride; docs/results.md, Speed); default: the model's (1: every window)")
    add_runtime(p)
    p.add_argument("--tlog", default=None, metavar="FILE", help="write the whole session (autopilot, ground stations, estimates) as a tlog")
    p.add_argument("--rate", type=float, default=50.0, metavar="HZ", help="estimates per second of autopilot time (default 50)")
    p.add_argument("--diag-rate", type=float, default=10.0, metavar="HZ", help="diagnostics per second (default 10; 0 = none)")
    p.add_argument("--imu", type=int, default=0, metavar="N", help="IMU instance to use (default 0)")
    p.add_argument("--min-imu-rate", type=float, default=50.0, metavar="HZ",
                   help="below this IMU rate (less 10 %%, for 2 s) ask the autopilot for more "
                        "(MAV_CMD_SET_MESSAGE_INTERVAL; default 50; 0: never); not granted: a warning, and the estimates "
                        "go on (withheld only below 20 Hz, too slow to estimate from)")
    p.add_argument("--request-imu-rate", type=float, default=200.0, metavar="HZ", help="IMU rate to ask for (default 200)")
    p.add_argument("--sysid", type=int, default=None, metavar="N", help="the autopilot's system id (default: the first seen)")
    p.add_argument("--compid", type=int, default=191, metavar="N", help="our component id (default 191, MAV_COMP_ID_ONBOARD_COMPUTER)")
    p.add_argument("--estimate-as", choices=list(ESTIMATE_AS), default=DEFAULT_ESTIMATE_AS,
                   help="how the estimate is sent: named_value (default; NAMED_VALUE_FLOAT tp_roll, tp_pitch, tp_yaw in deg: "
                        "never drives a ground station's HUD), debug_vect (DEBUG_VECT TP_RPY, deg) or attitude_quaternion "
                        "(ATTITUDE + ATTITUDE_QUATERNION: some QGroundControl versions may then switch the HUD between "
                        "the autopilot and this component)")
    p.add_argument("--estimates-to-master", action="store_true",
                   help="also send estimates to the autopilot (it may route them to its other links)")
    p.add_argument("--worker", choices=["process", "thread"], default="process",
                   help="run the estimator in a child process (default: never delays forwarding) or a thread")
    p.add_argument("--max-age", type=float, default=0.2, metavar="S",
                   help="drop IMU samples older than this when the estimator gets to them (default 0.2 s)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds")
    p.add_argument("--status-interval", type=float, default=None, metavar="S",
                   help="seconds between status lines (default 0.5 on a terminal, 10 otherwise)")
    p.add_argument("--view", action="store_true",
                   help="show TE-PINN beside the autopilot's attitude live in the Rerun viewer (3-D body, roll/pitch/heading, "
                        "differences); needs a display and pip install 'tepinn-flight[view]'")
    p.add_argument("--rrd", default=None, metavar="FILE", help="record the same view to a Rerun file (open it later: rerun FILE)")
    p.add_argument("--summary-json", default=None, metavar="FILE", help="also write the exit summary as JSON")
    p.add_argument("-q", "--quiet", action="store_true", help="no status line and no summary")


def run(args) -> int:
    import json
    import signal
    import sys
    import threading
    from pathlib import Path

    from ..errors import ConfigError, TepinnError
    from ..live.bridge import Bridge, BridgeConfig
    from ..live.router import parse_endpoint
    from ..live.status import StatusPrinter
    from ..record import atomic_write, check_output
    from .paths import check_suffix, refuse_overwriting_inputs, refuse_same_outputs

    for spec in [args.master, *args.out]:
        parse_endpoint(spec)
    if args.imu < 0:
        raise ConfigError(f"--imu {args.imu}: an IMU instance is 0 or more")
    if args.status_interval is not None and not args.status_interval > 0:
        raise ConfigError("--status-interval must be > 0")
    named = [(flag, path, suffixes, what) for flag, path, suffixes, what in (
        ("--tlog", args.tlog, ("", ".tlog"), "a MAVLink telemetry log"),
        ("--summary-json", args.summary_json, ("", ".json"), "JSON"),
        ("--rrd", args.rrd, (".rrd",), "a Rerun recording")) if path]  # fmt: skip
    for flag, path, suffixes, what in named:
        check_suffix(flag, path, suffixes, what)
    outputs = [(flag, path) for flag, path, _, _ in named]
    refuse_same_outputs(outputs)
    if args.summary_json:  # written at the session's end: refused now, not after it (the others are opened now)
        check_output(args.summary_json)
    if args.model:
        model = Path(args.model)
        if not model.is_file():
            raise ConfigError(f"--model {args.model}: no such checkpoint")
    else:
        from ..model.checkpoint import default_model_path
        from ..model.runtime import default_onnx_path, resolve_runtime

        model = default_model_path()
        if resolve_runtime(model, args.runtime) == "onnx" and default_onnx_path().is_file():
            model = default_onnx_path()  # the shipped model, exported
        if not model.is_file():
            raise TepinnError("the shipped default model is missing from this installation; pass --model CKPT")
    from ..model.runtime import check_model

    check_model(model, args.runtime)  # a model or runtime the worker would refuse: one line now, not after routing
    refuse_overwriting_inputs(outputs, [model])
    cfg = BridgeConfig(
        master=args.master, outs=tuple(args.out), model_path=str(model), runtime=args.runtime, mode=args.mode, busy_stride=args.busy_stride, tlog_path=args.tlog, rate_hz=args.rate,
        diag_rate_hz=args.diag_rate, imu_instance=args.imu, min_imu_rate_hz=args.min_imu_rate,
        request_imu_rate_hz=args.request_imu_rate, sysid=args.sysid, compid=args.compid,
        estimates_to_master=args.estimates_to_master, estimate_as=args.estimate_as, worker=args.worker, max_sample_age_s=args.max_age,
        duration_s=args.duration, view=args.view, rrd_path=args.rrd,
    )  # fmt: skip
    status = StatusPrinter(sys.stderr, quiet=args.quiet, interval_s=args.status_interval)
    bridge = Bridge(cfg, status=status)
    stop = threading.Event()
    stopped_by = []  # the signal that ended the session, if one did

    def on_signal(signum, frame):  # noqa: ARG001
        stopped_by.append(signum)
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    status.note(f"tepinn-flight bridge: master {args.master} -> {', '.join(args.out) or 'no outs'}; model {model.name}")
    try:
        summary = bridge.run(stop)
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    if args.summary_json:
        text = json.dumps(summary, indent=2, default=str)
        atomic_write(args.summary_json, lambda tmp: Path(tmp).write_text(text))
    if not args.quiet:
        print(bridge.format_summary(summary))
    # stopped by Ctrl-C or SIGTERM: the summary as after --duration, and the exit status every verb gives a signal
    # (130 / 143; review59: 0 once routing had begun, 130 a second earlier)
    return {signal.SIGINT: 130, signal.SIGTERM: 143}.get(stopped_by[0], 0) if stopped_by else 0
