# Installs this package's Python library (src/igmm_layers) through catkin_python_setup(); not run directly.
from catkin_pkg.python_setup import generate_distutils_setup
from setuptools import setup

setup(**generate_distutils_setup(packages=["igmm_layers", "igmm_layers.sim"], package_dir={"": "src"}))
