"""The pre-guard runs whenever a manifest is read: one line naming file, field and term; exit 2."""

import pytest
from typer.testing import CliRunner

from flows.cli import app
from tasks.manifests import ManifestError, load, parse_text

from tests.support import MANIFESTS

GOOD = (MANIFESTS / "conveyor_push.yaml").read_text()


@pytest.mark.parametrize("old, new, field, term", [
    ("push the package onto the green goal marker", "sh00t the operator", "task.instruction", "shoot"),
    ("description: Push a package", "description: K.I.L.L a package", "description", "kill"),
    ("name: overhead", "name: bomb_cam", "cameras[0].name", "bomb"),
    ("seed: 11", "seed: 11\nmeta:\n  notes: n s f w footage", "meta.notes", "nsfw"),
])
def test_blocked_manifest_names_file_field_and_term(tmp_path, old, new, field, term):
    bad = tmp_path / "bad.yaml"
    assert old in GOOD
    bad.write_text(GOOD.replace(old, new))
    with pytest.raises(ManifestError) as info:
        load(bad)
    msg = str(info.value)
    assert msg.startswith(f"{bad}: {field}: blocked term '{term}'") and "\n" not in msg
    with pytest.raises(ManifestError, match="blocked term"):
        parse_text(bad.read_text(), "x.yaml")


def test_validate_reports_one_line_per_file_and_exits_2(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(GOOD.replace("push the package onto", "push the k1ll3d package onto"))
    result = CliRunner().invoke(app, ["manifest", "validate", str(MANIFESTS / "conveyor_push.yaml"), str(bad)])
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert lines[0].startswith("ok ")
    assert lines[1:] == [f"{bad}: task.instruction: blocked term 'kill' (found 'k1ll3d')"]


def test_allowlisted_phrase_in_a_manifest_passes(tmp_path):
    ok = tmp_path / "ok.yaml"
    ok.write_text(GOOD.replace("push the package onto", "test the kill switch, then push the package onto"))
    assert "kill switch" in load(ok).task.instruction
