"""Compatibility with the original mongodb_api: its parameters, topics, tags and documents."""
