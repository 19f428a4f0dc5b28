"""Frozen contracts shared by every stage. Imports nothing else of ours."""

SCHEMA_VERSION = 1  # of manifests and panel contracts (the warehouse has its own: warehouse.store)
