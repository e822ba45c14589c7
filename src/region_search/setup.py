# Installs this package's Python library (src/region_search) through catkin_python_setup(); not run directly.
from catkin_pkg.python_setup import generate_distutils_setup
from setuptools import setup

# ranking_weights.yaml: the shipped ranking settings, read next to region_search/ranking.py
setup(**generate_distutils_setup(packages=["region_search"], package_dir={"": "src"},
                                 package_data={"region_search": ["ranking_weights.yaml"]}))
