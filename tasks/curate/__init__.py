"""Curation stages: decode once, split scenes, filter, caption, dedup, encode, shard."""
