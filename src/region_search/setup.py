# Installs this package's Python library (src/region_search) through catkin_python_setup(); not run directly.
from catkin_pkg.python_setup import generate_distutils_setup
from setuptools import setup

setup(**generate_distutils_setup(packages=["region_search"], package_dir={"": "src"}))
