"""Simulation-based evaluation of the crowd model: the only part of traffic_gp that uses robot_sim.

`evaluation` scores models against the people simulator's truth and on held-out counts; `cli` is
the `crowd_model` command (train on simulated robots, plot against the truth, inspect model
files). robot_sim is a test dependency of traffic_gp: the core (everything outside this
subpackage) never imports it, so a robot installs the crowd model without the simulator.
"""
