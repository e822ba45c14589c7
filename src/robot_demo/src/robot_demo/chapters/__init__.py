"""Chapters of the workspace demo (robot_demo.app): each module has TITLE and run(demo)."""
