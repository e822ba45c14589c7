"""Simulated people for benchmarks, tests and the demo: demonstrator families at a joystick.

Product code (learning, planning, nodes) never imports this subpackage; it stands in for the
people who give demonstrations."""
from lfd_controller.sim.datasets import dart_demos, person_demos, unseen_layouts
from lfd_controller.sim.families import (
    FAMILIES,
    PotentialFieldDriver,
    PursuitVODriver,
    SamplingMPCDriver,
    SocialForceDriver,
    TangentSwerveDriver,
    YieldingDriver,
    make_person,
)
from lfd_controller.sim.person import (
    PERSON_MAPPING,
    Person,
    SimulatedPerson,
    draw_person,
    drive_figures,
    quantise,
)

__all__ = ["FAMILIES", "PERSON_MAPPING", "Person", "SimulatedPerson", "draw_person", "drive_figures",
           "quantise", "make_person", "TangentSwerveDriver", "PotentialFieldDriver", "PursuitVODriver",
           "SocialForceDriver", "SamplingMPCDriver", "YieldingDriver", "person_demos", "dart_demos",
           "unseen_layouts"]
