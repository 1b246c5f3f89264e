"""Recorded outputs of fixed small pipelines and their recorder (record.py)."""
