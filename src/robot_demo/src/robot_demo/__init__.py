"""The workspace demo (`make demo`, `python -m robot_demo`): a real roscore, a real database
server and the nodes of every package, shown working chapter by chapter.

The demo stands on top of the workspace: it starts the products and simulators through their
launch files and speaks to them through their ROS interfaces (topics, services), and it reads
the simulators' parameters from the same YAML files their launch files load. The program is
`robot_demo.app`; each chapter is a module of `robot_demo.chapters` with `TITLE` and `run(demo)`.
"""
__all__ = []
