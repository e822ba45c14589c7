# Installs this package's Python library (src/errand_nav) through catkin_python_setup(); not run directly.
from catkin_pkg.python_setup import generate_distutils_setup
from setuptools import setup

setup(**generate_distutils_setup(packages=["errand_nav", "errand_nav.sim"], package_dir={"": "src"}))
