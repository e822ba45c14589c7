# Installs this package's Python library (src/robot_demo) through catkin_python_setup(); not run directly.
from catkin_pkg.python_setup import generate_distutils_setup
from setuptools import setup

setup(**generate_distutils_setup(packages=["robot_demo", "robot_demo.chapters"], package_dir={"": "src"}))
