import json
import math

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from schemas.hashing import canonical_json, content_hash, stable_id
from schemas.manifest import ScenarioManifest, manifest_hash
from tasks.manifests import load, parse_text

from tests.support import REPO

BASE = load(REPO / "manifests" / "bin_pick_dim_forklift.yaml")
json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-10**9, 10**9) | st.floats(allow_nan=False, allow_infinity=False) | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=20,
)


def _shuffled(value, rnd):
    if isinstance(value, dict):
        items = list(value.items())
        rnd.shuffle(items)
        return {k: _shuffled(v, rnd) for k, v in items}
    if isinstance(value, list):
        return [_shuffled(v, rnd) for v in value]
    return value


@given(json_values, st.randoms())
def test_canonical_json_ignores_key_order(value, rnd):
    assert canonical_json(_shuffled(value, rnd)) == canonical_json(value)


def test_whole_floats_hash_like_ints_and_nan_is_refused():
    assert content_hash({"fps": 30}) == content_hash({"fps": 30.0})
    assert content_hash({"fps": 30}) != content_hash({"fps": 30.5})
    with pytest.raises(ValueError):
        canonical_json({"x": math.nan})


def test_stable_id_parts_do_not_blur():
    assert stable_id("ab", "c") != stable_id("a", "bc")
    assert stable_id("a", "b") == stable_id("a", "b")


@settings(max_examples=30, deadline=None)
@given(st.randoms(), st.sampled_from([False, True]), st.integers(0, 8))
def test_manifest_hash_ignores_key_order_and_yaml_style(rnd, flow_style, indent_extra):
    body = _shuffled(BASE.model_dump(mode="json"), rnd)
    body["stressors"] = rnd.sample(body["stressors"], len(body["stressors"]))  # a set: order is not meaning
    text = yaml.safe_dump(body, default_flow_style=flow_style, indent=2 + indent_extra % 4, sort_keys=False)
    assert manifest_hash(parse_text(text)) == manifest_hash(BASE)


def test_json_and_yaml_of_the_same_manifest_agree():
    as_json = json.dumps(BASE.model_dump(mode="json"))  # JSON is YAML too
    assert manifest_hash(parse_text(as_json)) == manifest_hash(BASE)


@pytest.mark.parametrize("path, value", [
    (("seed",), 8),
    (("horizon_s",), 6.5),
    (("task", "controller_noise"), 0.06),
    (("cameras", 0, "fps"), 25),
    (("cameras", 2, "resolution"), [96, 64]),
    (("stressors", 0, "lux"), 61),
    (("evaluation", "lift_height_m"), 0.2),
    (("name",), "bin-pick-other"),
])
def test_any_change_of_meaning_changes_the_hash(path, value):
    body = BASE.model_dump(mode="json")
    target = body
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    assert manifest_hash(ScenarioManifest.model_validate(body)) != manifest_hash(BASE)


def test_volatile_fields_do_not_change_the_hash():
    changed = BASE.model_copy(update={"description": "reworded", "meta": BASE.meta.model_copy(update={"author": "x"})})
    assert manifest_hash(changed) == manifest_hash(BASE)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), horizon=st.floats(0.1, 3600), lux=st.floats(0.01, 100_000))
def test_round_trip_through_json_and_yaml(seed, horizon, lux):
    body = BASE.model_dump(mode="json")
    body.update(seed=seed, horizon_s=horizon)
    body["stressors"][0]["lux"] = lux
    m = ScenarioManifest.model_validate(body)
    assert ScenarioManifest.model_validate_json(m.model_dump_json()) == m
    again = parse_text(yaml.safe_dump(m.model_dump(mode="json")))
    assert again == m and manifest_hash(again) == manifest_hash(m)
