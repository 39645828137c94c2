"""``tepinn-flight replay LOG --to ENDPOINT``: a vehicle emulator for the bridge and ground stations."""

from __future__ import annotations

from .helptext import add_examples

HELP = "play a log back as a live MAVLink 2 vehicle (tlog frames unchanged; other logs as an autopilot stream)"
DESCRIPTION = (
    "Vehicle emulator. A .tlog is played frame by frame, unchanged (ids, sequence numbers), with the "
    "timing of the messages' own time fields (time_boot_ms / time_usec), not the tlog's receive "
    "timestamps; frames without a time field are placed between their timed neighbours. DataFlash, "
    "ULog, BROAD and flight records (Parquet) are sent as an autopilot would: HEARTBEAT 1 Hz, the IMU at "
    "its logged rate (HIGHRES_IMU or SCALED_IMU) and ATTITUDE + ATTITUDE_QUATERNION from the reference "
    "at <= 50 Hz. Pauses in the log longer than 2 s are shortened to 2 s."
)


def add_arguments(p) -> None:
    add_examples(p,
                 'tepinn-flight replay flight.tlog --to udpout:127.0.0.1:14550',
                 'tepinn-flight replay 00000042.BIN --to udpout:127.0.0.1:14550 --speed 2 --loop')
    p.add_argument("log", metavar="LOG", help=".tlog, DataFlash .bin/.log, ULog .ulg, BROAD .hdf5 or a flight record .parquet")
    p.add_argument("--to", required=True, metavar="ENDPOINT",
                   help="where to send: udpout:HOST:PORT (e.g. udpout:127.0.0.1:14550), udpin:, tcp:, tcpin: or a serial port")
    p.add_argument("--speed", type=float, default=1.0, help="playback speed factor (default 1.0 = real time)")
    p.add_argument("--loop", action="store_true", help="start again at the end (the clock jumps back, like a reboot)")
    p.add_argument("--imu-message", choices=["highres", "scaled"], default="highres",
                   help="IMU message for non-tlog logs: HIGHRES_IMU (float SI, default) or SCALED_IMU (int16 mG, mrad/s)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds of wall time")
    p.add_argument("--view", action="store_true",
                   help="show the autopilot's attitude it plays and the TE-PINN estimates a bridge sends back "
                        "(bridge --estimates-to-master) in the Rerun viewer; needs a display and pip install 'tepinn-flight[view]'")
    p.add_argument("--rrd", default=None, metavar="FILE", help="record the same view to a Rerun file (open it later: rerun FILE)")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")


def run(args) -> int:
    import signal
    import sys
    import threading

    from ..errors import ConfigError
    from ..live.replay import replay
    from ..live.router import parse_endpoint
    from ..live.view import ViewConfig
    from .paths import check_suffix, refuse_overwriting_inputs

    if not 0 < args.speed < float("inf"):
        raise ConfigError("--speed must be > 0 and finite")
    if args.duration is not None and not args.duration > 0:
        raise ConfigError("--duration must be > 0")
    parse_endpoint(args.to)  # a malformed endpoint fails before the log is read
    if args.rrd:
        check_suffix("--rrd", args.rrd, (".rrd",), "a Rerun recording")
        refuse_overwriting_inputs([("--rrd", args.rrd)], [args.log])
    stop = threading.Event()
    stopped_by = []  # the signal that stopped the playback, if one did

    def on_signal(signum, frame):  # noqa: ARG001
        stopped_by.append(signum)
        stop.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}

    def opened(link):
        if not args.quiet:
            sys.stderr.write(f"tepinn-flight replay: playing {args.log} to {args.to} at {args.speed:g}x\n")
            sys.stderr.flush()

    try:
        view = ViewConfig(spawn=args.view, rrd_path=args.rrd) if args.view or args.rrd else None
        out = replay(args.log, args.to, speed=args.speed, loop=args.loop, imu_message=args.imu_message,
                     duration_s=args.duration, stop=stop, on_open=opened, view=view)  # fmt: skip
    finally:
        for s, h in old.items():
            signal.signal(s, h)
    if not args.quiet:
        late = out["lateness_ms"]
        lat = f"lateness p99 {late['p99']:.2f} ms, max {late['max']:.2f} ms" if late.get("n") else "nothing sent"
        print(f"replayed {out['messages_sent']} messages ({out['log_s']:.1f} s of log, {out['loops']} pass(es)) "
              f"in {out['wall_s']:.1f} s; {lat}")  # fmt: skip
    # stopped by Ctrl-C or SIGTERM: the summary, then the exit status every verb gives a signal (130 / 143; review61:
    # 0, as after the whole log); the log's end or --duration: 0
    return {signal.SIGINT: 130, signal.SIGTERM: 143}.get(stopped_by[0], 0) if stopped_by else 0
