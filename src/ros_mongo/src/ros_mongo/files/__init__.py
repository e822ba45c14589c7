"""Bag and MCAP files: one reader / writer shape, a format registry, import and export."""
