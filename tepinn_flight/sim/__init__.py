"""JSBSim-based flight simulation: truth dynamics, maneuvers, sensor model and records."""

from pathlib import Path

#: The checkout's ``flight_sims`` folder: aircraft definitions, sensor presets, campaigns.
FLIGHT_SIMS_DIR = Path(__file__).resolve().parents[2] / "flight_sims"
