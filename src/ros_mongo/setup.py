# Installs this package's Python library (src/ros_mongo) through catkin_python_setup(); not run directly.
from catkin_pkg.python_setup import generate_distutils_setup
from setuptools import setup

PACKAGES = ["ros_mongo"] + [f"ros_mongo.{group}" for group in
                            ("compat", "files", "fleet", "messages", "recording", "replay", "storage")]

setup(**generate_distutils_setup(packages=PACKAGES, package_dir={"": "src"}))
