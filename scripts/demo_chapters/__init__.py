"""Chapters of the workspace demo (scripts/demo.py): each has TITLE and run(demo)."""
