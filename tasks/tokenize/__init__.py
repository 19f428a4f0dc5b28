"""Tokenize stage: decode curated shard clips, train the video tokenizer, write token shards.

Modules: `data` (shard clips decoded with PyAV), `train` (the training loop and PSNR),
`tokens` (safetensors checkpoints, token shard Parquet, lineage records).
"""
