"""The class of vehicle a log names — the one home of that mapping.

Readers write what the log says into a record's ``vehicle_type``: a DataFlash log its firmware's family
(``copter``, ``plane``, ``sub``…), a ULog or a tlog the autopilot's ``MAV_TYPE`` (``quadrotor``,
``fixed-wing`` / ``fixed_wing``, ``vtol-fixedrotor``…), our simulations ``multirotor`` or ``fixed-wing``,
BROAD ``handheld-imu``; the live bridge the heartbeat's ``MAV_TYPE`` the same way. :func:`vehicle_class`
folds those into the few classes the estimator's gates ask about (``AnchorConfig.speed_gate_shut_for``),
the fine-tuning's grouping of logs by vehicle reads, and :func:`mav_type_suffix` turns back into a heartbeat's
MAV_TYPE (a record replayed or written as a tlog). A name it does not know, or none, is :data:`UNKNOWN`: the
gates then act as they always did.
"""

from __future__ import annotations

MULTIROTOR = "multirotor"
FIXED_WING = "fixed-wing"
HANDHELD = "handheld"
OTHER = "other"
UNKNOWN = "unknown"
CLASSES = (MULTIROTOR, FIXED_WING, HANDHELD, OTHER, UNKNOWN)

_MULTIROTOR = ("copter", "quadrotor", "hexarotor", "octorotor", "tricopter", "coaxial", "dodecarotor", "decarotor",
               "multirotor", "quad")  # fmt: skip
_FIXED_WING = ("plane", "fixed-wing", "fixedwing", "glider")
_HANDHELD = ("handheld-imu", "handheld")
_UNKNOWN = ("", "unknown", "generic", "synthetic")


def vehicle_class(vehicle_type: str | None) -> str:
    """:data:`MULTIROTOR`, :data:`FIXED_WING`, :data:`HANDHELD`, :data:`OTHER` (a named vehicle of another
    kind: helicopter, VTOL, rover, boat, submarine…) or :data:`UNKNOWN` for a record's ``vehicle_type``; a class's own
    name gives itself."""
    name = str(vehicle_type or "").strip().lower().replace("_", "-")
    if name in _UNKNOWN or name.startswith("mav-type-") or name.isdigit():  # (an enum value no dialect names)
        return UNKNOWN
    if name in _MULTIROTOR:
        return MULTIROTOR
    if name in _FIXED_WING:
        return FIXED_WING
    if name in _HANDHELD:
        return HANDHELD
    return OTHER


def mav_type_suffix(vehicle_type: str | None) -> str:
    """The MAV_TYPE a heartbeat gives ``vehicle_type`` (``MAV_TYPE_`` + this): a multirotor ``QUADROTOR``, a fixed
    wing ``FIXED_WING``, anything else ``GENERIC``."""
    return {MULTIROTOR: "QUADROTOR", FIXED_WING: "FIXED_WING"}.get(vehicle_class(vehicle_type), "GENERIC")
