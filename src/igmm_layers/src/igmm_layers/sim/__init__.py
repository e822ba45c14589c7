"""Simulation-based evaluation of the object layers (test and benchmark oracles, not the product).

`metrics`: OSPA and matching precision/recall against ground truth; `reference`: the literal
published IGMM update, the slow peer the fast model is checked against. Only this subpackage
and the tests may import the simulator (robot_sim, a test dependency).
"""
