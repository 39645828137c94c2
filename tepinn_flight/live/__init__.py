"""Live MAVLink: the companion bridge (``tepinn-flight bridge``) and the vehicle emulator (``replay``).

Modules
    ``messages``  pure encoders of everything the bridge and the emulator send (MAVLink 2)
    ``inputs``    pure decoders of what the bridge reads: IMU samples (units per autopilot, the
                  rules of :mod:`tepinn_flight.ingest.tlog`) and the autopilot's EKF attitude, and
                  the EKF-vs-estimate comparison; the bridge's estimate read back (the emulator)
    ``router``    endpoints (``udpin:``/``udpout:``/``tcp:``/``tcpin:``/serial) through pymavlink's
                  ``mavlink_connection``, datagram-safe parsing, raw forwarding
    ``worker``    the estimator off the forwarding path: a child process (default) or a thread,
                  fed through a bounded non-blocking pipe; stale samples are dropped
    ``bridge``    the select loop and the wiring of the bridge's rooms below (``BridgeConfig``)
    ``forwarding`` the transparent routing autopilot <-> ground stations (own echoes, unknown ids)
    ``session_tlog`` the bridge's session tlog (``--tlog``, written atomically)
    ``autopilot`` which autopilot (HEARTBEAT), seen / lost, its boot clock, our encoder
    ``imu_stream`` the autopilot's IMU stream: which message, order, rate, asking for a faster one
    ``estimate_path`` samples into the estimator worker (restarts), estimates out as MAVLink
    ``comparison`` TE-PINN vs the autopilot's EKF: pairing, the difference histogram, the view's feed
    ``replay``    tlog playback on the messages' own clocks; DataFlash/ULog/records as a live stream
    ``status``    latency histograms, rate meters, the status line and the exit summary
    ``view``      the live view (``--view``/``--rrd``): TE-PINN beside the autopilot's attitude in Rerun

pymavlink is imported through :func:`mavutil` (its home: :mod:`tepinn_flight.mavlink_dialect`) so
that ``MAVLINK20=1`` is always set first (``mavlink.md`` §2): without it pymavlink speaks MAVLink 1
and lacks the v2 extension fields.
"""

from __future__ import annotations

from ..mavlink_dialect import dialect, mavutil  # noqa: F401 - the dialect's one home, re-exported

#: ``MAV_COMP_ID_ONBOARD_COMPUTER``: the bridge's own component id.
MAV_COMP_ID_ONBOARD_COMPUTER = 191
MAV_COMP_ID_AUTOPILOT1 = 1
