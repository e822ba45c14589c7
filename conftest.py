# The shared test harness (real roscore, roslaunch, database servers, Xvfb) for every test in the
# workspace: see src/ros_harness/src/ros_harness/pytest_plugin.py.
pytest_plugins = ["ros_harness.pytest_plugin"]
