import pytest

from tasks.manifests import MAX_BYTES, ManifestError, load, parse_text

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
