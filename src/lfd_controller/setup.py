# Installs this package's Python library (src/lfd_controller) through catkin_python_setup(); not run directly.
from catkin_pkg.python_setup import generate_distutils_setup
from setuptools import setup

setup(**generate_distutils_setup(packages=["lfd_controller", "lfd_controller.sim"], package_dir={"": "src"}))
