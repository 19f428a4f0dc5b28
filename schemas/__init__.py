"""Frozen contracts shared by every stage. Imports nothing else of ours."""

SCHEMA_VERSION = 2
