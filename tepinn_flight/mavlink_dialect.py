"""The MAVLink dialect, loaded in one place for every part that speaks MAVLink: the tlog scanner
(:mod:`.ingest.mavlink_scan`), the tlog writer (:mod:`.tlog_writer`) and the live side
(:mod:`.live`: connections, message encoders and decoders).

pymavlink is imported through :func:`mavutil` so that ``MAVLINK20=1`` is always set first
(``mavlink.md`` §2): without it pymavlink speaks MAVLink 1 and lacks the v2 extension fields. The
dialect is the one ``mavutil`` loads: ``all`` (a superset of ``common`` and ``ardupilotmega``)
unless ``MAVLINK_DIALECT`` names another.
"""

from __future__ import annotations

import os


def mavutil():
    """``pymavlink.mavutil`` with the MAVLink 2 dialect loaded (whatever was imported before)."""
    os.environ["MAVLINK20"] = "1"
    from pymavlink import mavutil as mu  # noqa: PLC0415 - must follow the environment variable

    if getattr(mu.mavlink, "WIRE_PROTOCOL_VERSION", "1.0") != "2.0":
        mu.set_dialect(mu.current_dialect)
    return mu


def dialect():
    """The MAVLink 2 dialect module (message classes, enums, constants, ``MAVLink`` encoder)."""
    return mavutil().mavlink
