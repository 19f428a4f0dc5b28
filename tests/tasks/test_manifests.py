import pytest

from tasks.manifests import MAX_BYTES, ManifestError, load, parse_text, safe_mapping

from tests.support import MANIFESTS

GOOD = (MANIFESTS / "conveyor_push.yaml").read_text()


def test_error_names_file_field_and_problem(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(GOOD.replace("fps: 30", "fps: 100000"))
    with pytest.raises(ManifestError) as info:
        load(bad)
    msg = str(info.value)
    assert msg.startswith(str(bad)) and "cameras.0.fps" in msg and "240" in msg
    assert "\n" not in msg


@pytest.mark.parametrize("text, problem", [
    ("", "empty manifest"),
    ("- a\n- b\n", "top level must be a mapping"),
    ("name: [unclosed\n", "not valid YAML"),
    ("!!python/object/apply:os.system ['echo pwned']\n", "not valid YAML"),
    ("a: !!python/name:os.system\n", "not valid YAML"),
    ("a: &x [1, 2]\nb: *x\n", "alias"),
    ("a: " + "[" * 40 + "]" * 40 + "\n", "nested deeper"),
    ("a: [" + ", ".join(["1"] * 6000) + "]\n", "YAML nodes"),
])
def test_hostile_yaml_is_refused_before_construction(text, problem):
    with pytest.raises(ManifestError) as info:
        parse_text(text, "x.yaml")
    assert problem in str(info.value) and str(info.value).startswith("x.yaml")


def test_billion_laughs_is_refused():
    lines = ["a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    lines += [f"a{i}: &a{i} [*a{i-1}, *a{i-1}, *a{i-1}, *a{i-1}, *a{i-1}]" for i in range(1, 10)]
    with pytest.raises(ManifestError, match="alias"):
        parse_text("\n".join(lines))


def test_huge_file_is_refused_without_parsing(tmp_path):
    big = tmp_path / "big.yaml"
    big.write_text("# " + "x" * (MAX_BYTES + 10))
    with pytest.raises(ManifestError, match="larger than"):
        load(big)


def test_directory_and_missing_file(tmp_path):
    with pytest.raises(ManifestError, match="not a file"):
        load(tmp_path)
    with pytest.raises(ManifestError, match="missing.yaml: no such file"):
        load(tmp_path / "missing.yaml")


def test_nan_in_yaml_is_refused():
    with pytest.raises(ManifestError, match="horizon_s"):
        parse_text(GOOD.replace("horizon_s: 5.0", "horizon_s: .nan"))


@pytest.mark.parametrize("text, field, lines", [
    ("seed: 1\nname: a\nseed: 2\n", "seed", (1, 3)),
    ("task:\n  kind: push\n  kind: drive\n", "task.kind", (2, 3)),
    ("cameras:\n  - name: a\n    fps: 30\n    fps: 60\n", "cameras.0.fps", (3, 4)),
    ("seed: 1\n'seed': 2\n", "seed", (1, 2)),  # quoting does not make it another key
    ("a: {x: 1, x: 2}\n", "a.x", (1, 1)),
])
def test_duplicate_keys_are_refused_at_any_depth(text, field, lines):
    # PyYAML keeps the last of two equal keys without a word (issue 26).
    with pytest.raises(ManifestError) as info:
        parse_text(text, "x.yaml")
    msg = str(info.value)
    assert msg.startswith(f"x.yaml: {field}: ") and "twice" in msg and f"lines {lines[0]} and {lines[1]}" in msg
    assert "\n" not in msg


def test_merge_keys_are_refused():
    # Without aliases a merge key only restates keys inline: a duplicate key by another name.
    with pytest.raises(ManifestError, match=r"x.yaml: task: .*merge key"):
        parse_text("task:\n  <<: {kind: drive}\n  kind: push\n", "x.yaml")


def test_every_reader_of_safe_yaml_refuses_duplicate_keys():
    from tasks.curate.config import ConfigError
    from tasks.panels.grid import GridError, parse_grid

    with pytest.raises(ConfigError, match=r"c.yaml: min_seconds: given twice"):
        safe_mapping("min_seconds: 1\nmin_seconds: 2\n", "c.yaml", "curate config", ConfigError)
    with pytest.raises(GridError, match=r"g.yaml: episodes: given twice"):
        parse_grid("name: g\nepisodes: 2\nepisodes: 3\n", "g.yaml")


@pytest.mark.parametrize("objects, problem", [
    ("[]", "at least one object"),
    ("[package, distractor]", "distractor_1"),
    ("[package, package]", "repeat"),
])
def test_object_lists_that_would_crash_the_scene_are_refused(tmp_path, objects, problem):
    path = tmp_path / "m.yaml"
    path.write_text(GOOD.replace("objects: [package]", f"objects: {objects}"))
    with pytest.raises(ManifestError) as info:
        load(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: task.objects: ") and problem in msg and "\n" not in msg
