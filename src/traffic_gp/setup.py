# Installs this package's Python library (src/traffic_gp) through catkin_python_setup(); not run directly.
from catkin_pkg.python_setup import generate_distutils_setup
from setuptools import setup

setup(**generate_distutils_setup(packages=["traffic_gp", "traffic_gp.sim"], package_dir={"": "src"}))
