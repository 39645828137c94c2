"""JSBSim-based flight simulation: truth dynamics, maneuvers, sensor model and records."""
