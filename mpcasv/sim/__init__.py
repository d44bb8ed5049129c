"""Closed-loop simulator: scenarios, the simulation loop, run records and plots."""
