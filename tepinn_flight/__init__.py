"""tepinn-flight: attitude estimation for drones and aircraft with TE-PINN.

See :mod:`tepinn_flight.conventions` for frames, quaternion order and units used everywhere.
"""

__version__ = "0.1.0"
