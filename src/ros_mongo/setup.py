# Installs this package's Python library (src/ros_mongo) through catkin_python_setup(); not run directly.
from catkin_pkg.python_setup import generate_distutils_setup
from setuptools import setup

setup(**generate_distutils_setup(packages=["ros_mongo", "ros_mongo.backends"], package_dir={"": "src"}))
