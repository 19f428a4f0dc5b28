"""The one canonical hash: sorted-key JSON with volatile fields left out."""

from __future__ import annotations

import hashlib
import json
import math
from typing import Any

from pydantic import BaseModel


def _normalise(value: Any) -> Any:
    # Floats that are whole numbers hash like ints so `fps: 30` and `fps: 30.0` agree.
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError("non-finite numbers have no canonical form")
        return int(value) if value.is_integer() else value
    if isinstance(value, int):
        return value
    if isinstance(value, dict):
        return {str(k): _normalise(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_normalise(v) for v in value]
    raise TypeError(f"cannot canonicalise {type(value).__name__}")


def canonical_json(value: Any) -> str:
    """Sorted keys, no whitespace, ASCII only: one text per meaning."""
    if isinstance(value, BaseModel):
        value = value.model_dump(mode="json")
    return json.dumps(_normalise(value), sort_keys=True, separators=(",", ":"), ensure_ascii=True)


def sha256_text(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def content_hash(value: Any) -> str:
    return sha256_text(canonical_json(value))


def sha256_file(path: str, chunk: int = 1 << 20) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            digest.update(block)
    return digest.hexdigest()


def stable_id(*parts: str, length: int = 24) -> str:
    """A short deterministic id from its identity parts (NUL-joined, so parts never blur)."""
    return hashlib.sha256("\0".join(parts).encode("utf-8")).hexdigest()[:length]
