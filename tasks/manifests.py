"""Read, validate and hash scenario manifests. Safe YAML only; every error names file and field."""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

import yaml
from yaml.constructor import SafeConstructor
from pydantic import BaseModel, ValidationError

from schemas.hashing import canonical_json
from schemas.manifest import FieldError, ScenarioManifest
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch, ManifestRow
from tasks.guard.text import GuardError, check_fields

MAX_BYTES = 256 * 1024
MAX_NODES = 5_000
MAX_DEPTH = 16
Model = TypeVar("Model", bound=BaseModel)


class ManifestError(ValueError):
    """One line: the file, the field and the problem."""


def _check_shape(node: yaml.Node, where: str) -> None:
    # Walk the composed tree before constructing anything: aliases (billion laughs),
    # depth and size are refused here, so nothing big is ever built; so are repeated keys,
    # which construction would drop silently (the last one wins).
    stack = [(node, 1, "")]
    count = 0
    keys = SafeConstructor()  # builds scalar keys only, to compare them as the mapping would
    while stack:
        current, depth, field = stack.pop()
        count += 1
        if count > MAX_NODES:
            raise ManifestError(f"{where}: more than {MAX_NODES} YAML nodes")
        if depth > MAX_DEPTH:
            raise ManifestError(f"{where}: nested deeper than {MAX_DEPTH} levels")
        if isinstance(current, yaml.MappingNode):
            _check_keys(current, where, field, keys)
            for key, value in current.value:
                inner = _dotted(field, key.value) if isinstance(key, yaml.ScalarNode) else field
                stack += [(key, depth + 1, field), (value, depth + 1, inner)]
        elif isinstance(current, yaml.SequenceNode):
            stack.extend((n, depth + 1, _dotted(field, i)) for i, n in enumerate(current.value))


def _dotted(field: str, part) -> str:
    return f"{field}.{part}" if field else str(part)


def _check_keys(mapping: yaml.MappingNode, where: str, field: str, keys: SafeConstructor) -> None:
    seen: dict = {}
    for key, _ in mapping.value:
        line = key.start_mark.line + 1
        if key.tag == "tag:yaml.org,2002:merge":
            # Without aliases a merge key only restates keys inline: a repeated key by another name.
            raise ManifestError(f"{where}: {field or '(top level)'}: YAML merge key << is not allowed (line {line})")
        if not isinstance(key, yaml.ScalarNode):
            continue
        value = keys.construct_object(key)
        if value in seen:
            raise ManifestError(f"{where}: {_dotted(field, key.value)}: given twice (lines {seen[value]} and {line}); "
                                f"YAML would keep the last one without a word")
        seen[value] = line


class _NoAliasLoader(yaml.SafeLoader):
    def compose_node(self, parent, index):  # noqa: D401 - PyYAML hook
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise ManifestError(f"YAML alias *{event.anchor} is not allowed (line {event.start_mark.line + 1})")
        return super().compose_node(parent, index)


def safe_mapping(text: str, where: str, what: str = "manifest", error: type[ValueError] = ManifestError) -> dict:
    """The top-level mapping of a small YAML text: safe YAML only (no tags, no aliases, bounded
    size and depth); ``error`` names ``where`` and the problem otherwise."""
    if len(text.encode("utf-8")) > MAX_BYTES:
        raise error(f"{where}: larger than {MAX_BYTES} bytes")
    try:
        loader = _NoAliasLoader(text)
        try:
            node = loader.get_single_node()
        finally:
            loader.dispose()
        if node is None:
            raise error(f"{where}: empty {what}")
        _check_shape(node, where)
        data = yaml.load(text, Loader=yaml.SafeLoader)  # safe: no object construction from tags
    except (ManifestError, error) as exc:
        msg = str(exc)
        raise error(msg if msg.startswith(where) else f"{where}: {msg}") from None
    except yaml.YAMLError as exc:
        problem = " ".join(str(exc).split())
        raise error(f"{where}: not valid YAML: {problem}") from None
    except RecursionError:
        raise error(f"{where}: nested too deeply") from None
    if not isinstance(data, dict):
        raise error(f"{where}: the top level must be a mapping, not {type(data).__name__}")
    return data


def validated(model: type[Model], data: dict, where: str, error: type[ValueError] = ManifestError) -> Model:
    """``model`` validated from ``data``; ``error`` names ``where``, each field and its problem otherwise."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        errors = exc.errors()
        # Pydantic also calls a list too short when its only items failed: that is no news.
        inner = {e["loc"][:k] for e in errors for k in range(len(e["loc"]))}
        problems = [f"{'.'.join(str(p) for p in _location(e)) or '(top level)'}: {_message(e)}" for e in errors
                    if not (e["type"] == "too_short" and e["loc"] in inner)]
        raise error(f"{where}: {'; '.join(problems)}") from None


def _field_error(error: dict) -> FieldError | None:
    cause = (error.get("ctx") or {}).get("error")
    return cause if isinstance(cause, FieldError) else None


def _location(error: dict) -> tuple:
    # A FieldError names a field below the validator that raised it (cameras.1.name below the
    # manifest): that field is the location.
    cause = _field_error(error)
    return tuple(error["loc"]) + tuple(cause.field.split(".")) if cause else tuple(error["loc"])


def _message(error: dict) -> str:
    cause = _field_error(error)
    return cause.problem if cause else error["msg"]


def parse_text(text: str, where: str = "<manifest>") -> ScenarioManifest:
    manifest = validated(ScenarioManifest, safe_mapping(text, where), where)
    try:
        check_fields(manifest)  # the pre-guard: every text field, after validation (issue 10)
    except GuardError as exc:
        raise ManifestError(f"{where}: {exc}") from None
    return manifest


def read_text(path: Path, error: type[ValueError] = ManifestError) -> str:
    """A small UTF-8 YAML file's text; ``error`` names the file and the problem otherwise."""
    try:
        if not path.exists():
            raise error(f"{path}: no such file")
        if not path.is_file():
            raise error(f"{path}: not a file")
        if path.stat().st_size > MAX_BYTES:
            raise error(f"{path}: larger than {MAX_BYTES} bytes")
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{path}: cannot read: {exc}") from None


def load(path: Path | str) -> ScenarioManifest:
    path = Path(path)
    return parse_text(read_text(path), str(path))


def dump_yaml(manifest: ScenarioManifest) -> str:
    return yaml.safe_dump(manifest.model_dump(mode="json"), sort_keys=False)


def lineage(manifest: ScenarioManifest, source_uri: str | None = None) -> LineageBatch:
    """The manifest row and its artifact (the root every other artifact descends from)."""
    digest = manifest.sha256
    row = ManifestRow(manifest_hash=digest, name=manifest.name, schema_version=manifest.schema_version,
                      body=canonical_json(manifest), source_uri=source_uri, parent_hash=manifest.parent)
    art = ArtifactRecord(artifact_id=digest, kind="manifest", uri=source_uri, sha256=digest,
                         manifest_hash=digest, attrs={"name": manifest.name})
    batch = LineageBatch(manifests=[row], artifacts=[art])
    if manifest.parent:
        batch.edges.append(EdgeRecord(parent_id=manifest.parent, child_id=digest, relation="derived_manifest"))
    return batch
