"""Issue 5: hostile manifests write nothing, loaders stay safe, audit parameters stay bound.

Unit checks of each refusal live in tests/tasks/test_manifests.py and tests/schemas/; here each
hostile manifest goes through the commands that would act on it, and the data root must stay
empty (no warehouse, no file) while the object-constructing tag must not have run.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from typer.testing import CliRunner

from flows.cli import app
from schemas.records import ArtifactRecord, EdgeRecord, LineageBatch
from tasks.curate.shards import read_shard
from warehouse.store import Warehouse

from tests.support import (MANIFESTS, REPO, curate_command, escaped_name, good_videos, lineage_problems, rename_to,
                           scene_frames, write_video)

runner = CliRunner()
GOOD = (MANIFESTS / "conveyor_push.yaml").read_text()
PWNED = "/tmp/worldline-pwned-by-yaml"


def _deep(levels: int) -> str:
    return "meta:\n  notes: ok\nx: " + "{a: " * levels + "1" + "}" * levels + "\n"


HOSTILE = {
    "mjcf climbs out": GOOD.replace("robot: builtin_arm", "robot: builtin_arm\n  mjcf: ../../../etc/passwd"),
    "mjcf absolute": GOOD.replace("robot: builtin_arm", "robot: builtin_arm\n  mjcf: /etc/passwd"),
    "robot name is a path": GOOD.replace("robot: builtin_arm", "robot: ../../etc"),
    "camera name is a path": GOOD.replace("- name: overhead", "- name: ../../overhead", 1),
    "manifest name is a path": GOOD.replace("name: conveyor-push", "name: ../conveyor-push", 1),
    "absurd resolution": GOOD.replace("resolution: [128, 128]", "resolution: [100000, 100000]"),
    "absurd fps": GOOD.replace("fps: 30", "fps: 10000"),
    "absurd horizon": GOOD.replace("horizon_s: 5.0", "horizon_s: 1.0e+12"),
    "nan": GOOD.replace("horizon_s: 5.0", "horizon_s: .nan"),
    "infinity": GOOD.replace("horizon_s: 5.0", "horizon_s: .inf"),
    "deep nesting": GOOD + _deep(40),
    "huge file": GOOD + "# " + "x" * (300 * 1024) + "\n",
    "many nodes": GOOD + "extra: [" + ", ".join(["1"] * 6000) + "]\n",
    "billion laughs": "a: &a [x, x, x, x]\nb: &b [*a, *a, *a, *a]\nc: [*b, *b, *b, *b]\n" + GOOD,
    "object tag": f"!!python/object/apply:os.system ['touch {PWNED}']\n",
    "object tag inside": GOOD.replace("seed: 11", f"seed: !!python/object/apply:os.system ['touch {PWNED}']"),
    "name tag": GOOD.replace("seed: 11", "seed: !!python/name:os.system"),
}


def test_the_good_manifest_is_what_the_cases_edit():
    for needle in ("robot: builtin_arm", "- name: overhead", "name: conveyor-push", "resolution: [128, 128]",
                   "fps: 30", "horizon_s: 5.0", "seed: 11"):
        assert needle in GOOD, needle  # else a case below would test the good manifest


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_hostile_manifest_is_refused_and_nothing_is_written(case, tmp_path_factory, data_root):
    folder = tmp_path_factory.mktemp("hostile")
    path = folder / "hostile.yaml"
    path.write_text(HOSTILE[case])
    (folder / "clip.mp4").write_bytes(b"")
    for args in (["manifest", "validate", str(path)], ["register", str(path)],
                 ["curate", str(folder / "clip.mp4"), "--manifest", str(path)]):
        result = runner.invoke(app, args)
        assert result.exit_code == 2, (case, args, result.output)
        lines = [line for line in result.output.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith(str(path)), (case, result.output)
    assert list(data_root.iterdir()) == [], case  # no warehouse, no artifact, not even a folder
    assert not Path(PWNED).exists()


# -- safe loading -----------------------------------------------------------------------------
SCANNED = ("flows", "tasks", "models", "schemas", "warehouse", "bench")


def unsafe_loads(source: str) -> list[str]:
    """Calls in ``source`` that can run code from a file: torch.load without weights_only=True,
    pickle/dill/joblib/marshal loads, yaml.load/load_all with a non-safe Loader (or none),
    yaml.unsafe_load/full_load, numpy.load with allow_pickle=True."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Call):
            continue
        name = ast.unparse(node.func)
        keywords = {k.arg: k.value for k in node.keywords}

        def true(key: str) -> bool:
            return isinstance(keywords.get(key), ast.Constant) and keywords[key].value is True

        line = f"line {node.lineno}: {ast.unparse(node)[:80]}"
        if name.endswith("torch.load") or name == "load" and "weights_only" in keywords:
            if not true("weights_only"):
                found.append(line)
        elif name.split(".")[0] in ("pickle", "dill", "joblib", "marshal", "cloudpickle", "_pickle") and "load" in name:
            found.append(line)
        elif name in ("yaml.unsafe_load", "yaml.full_load", "yaml.unsafe_load_all", "yaml.full_load_all"):
            found.append(line)
        elif name in ("yaml.load", "yaml.load_all"):
            loader = keywords.get("Loader") or (node.args[1] if len(node.args) > 1 else None)
            if loader is None or "Safe" not in ast.unparse(loader) and "NoAlias" not in ast.unparse(loader):
                found.append(line)
        elif name in ("np.load", "numpy.load") and true("allow_pickle"):
            found.append(line)
    return found


@pytest.mark.parametrize("snippet, unsafe", [
    ("torch.load(p)", True),
    ("torch.load(p, weights_only=False)", True),
    ("torch.load(p, map_location='cpu', weights_only=True)", False),
    ("pickle.load(f)", True),
    ("pickle.loads(b)", True),
    ("yaml.load(t)", True),
    ("yaml.load(t, Loader=yaml.Loader)", True),
    ("yaml.load(t, Loader=yaml.SafeLoader)", False),
    ("yaml.unsafe_load(t)", True),
    ("yaml.safe_load(t)", False),
    ("np.load(p, allow_pickle=True)", True),
    ("np.load(p)", False),
    ("safetensors.torch.load_file(p)", False),
])
def test_the_scanner_tells_safe_from_unsafe(snippet, unsafe):
    assert bool(unsafe_loads(snippet)) is unsafe


def test_no_code_loads_files_unsafely():
    bad = {str(path.relative_to(REPO)): hits for folder in SCANNED for path in sorted((REPO / folder).rglob("*.py"))
           if (hits := unsafe_loads(path.read_text()))}
    assert bad == {}, "checkpoints: safetensors or torch.load(..., weights_only=True); YAML: safe loaders only"


# -- audit parameters are bound, through the command line -------------------------------------
INJECTIONS = [
    ("manifest_artifacts", "--manifest", "{m}' OR '1'='1"),
    ("rejections", "--manifest", "{m}' UNION SELECT 1, 2, 3, 4 --"),
    ("runs", "--manifest", "x'); DROP TABLE runs; --"),
    ("ancestry", "--artifact", "clip1'; DROP TABLE edges; --"),
    ("ancestry_walk", "--artifact", "clip1' OR 1=1 --"),
    ("metrics", "--manifest", "$manifest"),
]


@pytest.mark.parametrize("name, option, value", INJECTIONS)
def test_sql_injection_through_the_audit_command_is_inert(name, option, value, data_root):
    m = "a" * 64
    with Warehouse(data_root / "lineage.duckdb") as wh:
        wh.write(LineageBatch(
            artifacts=[ArtifactRecord(artifact_id=i, kind=k, uri=i, sha256=None, manifest_hash=m)
                       for i, k in ((m, "manifest"), ("raw1", "raw_video"), ("clip1", "clip"))],
            edges=[EdgeRecord(parent_id=m, child_id="raw1"), EdgeRecord(parent_id="raw1", child_id="clip1")]))
        before = wh.counts()
    honest = runner.invoke(app, ["audit", name, option, "clip1" if option == "--artifact" else m, "--format", "json"])
    assert honest.exit_code == 0, honest.output
    result = runner.invoke(app, ["audit", name, option, value.format(m=m), "--format", "json"])
    # the whole string was one bound value: it names no id, so the audit is refused, in one line
    assert result.exit_code == 2 and result.output.strip() == f"{option} {value.format(m=m)}: no such {option[2:]} in lineage"
    with Warehouse(data_root / "lineage.duckdb", read_only=True) as wh:
        assert wh.counts() == before


# -- file names that are not UTF-8 (issue 26) -------------------------------------------------
def test_undecodable_file_names_are_curated_or_quarantined_and_recorded_escaped(prefect_harness, tmp_path):
    """A name with an invalid UTF-8 byte once failed the whole batch (DuckDB: "Malformed JSON ...
    invalid high surrogate", exit 1, nothing recorded). Now a good video under such a name is
    curated, a broken one quarantined, and every record and message writes the name escaped."""
    from prefect.settings import PREFECT_API_URL

    inbox, root = tmp_path / "inbox", tmp_path / "root"
    good_videos(inbox, seeds=(0,))
    good = rename_to(write_video(inbox / "good.mp4", scene_frames(2)), b"good\xff.mp4")
    (inbox / "junk.mp4").write_bytes(b"\x00junk" * 400)
    junk = rename_to(inbox / "junk.mp4", b"junk\xfe.mp4")
    done = curate_command([inbox], root, api_url=PREFECT_API_URL.value())
    assert done.returncode == 1, done.stderr[-3000:]
    assert done.stdout.splitlines()[-1].endswith("1 of 3 inputs quarantined"), done.stdout
    assert f"quarantined {escaped_name(junk)}: " in done.stdout + done.stderr  # the flow's log

    db = root / "lineage.duckdb"
    with Warehouse(db, read_only=True) as wh:
        raw = dict(wh.query("SELECT uri, attrs->>'quarantined' FROM artifacts WHERE kind = 'raw_video'")[1])
        rejected = wh.query("SELECT a.uri, r.reason, r.detail FROM rejections r JOIN artifacts a USING (artifact_id) "
                            "WHERE a.kind = 'raw_video'")[1]
        sources = {r[0] for r in wh.query("SELECT attrs->>'source' FROM stage_runs WHERE stage = 'analyse'")[1]}
        (params, message), = wh.query("SELECT params, message FROM runs")[1]
        kept = {r[0] for r in wh.query("SELECT artifact_id FROM artifacts WHERE kind = 'clip' AND uri IS NOT NULL")[1]}
    assert raw == {str(inbox / "good_0.mp4"): None, escaped_name(good): None, escaped_name(junk): "true"}
    assert [(uri, reason) for uri, reason, _ in rejected] == [(escaped_name(junk), "unreadable")]
    assert rejected[0][2].startswith(escaped_name(junk)) and message == "partial: 1 of 3 inputs failed"
    assert sources == {str(inbox / "good_0.mp4"), escaped_name(good)}
    assert str(inbox) in params
    rows = [r for p in (root / "shards").rglob("*.parquet") for r in read_shard(p).select(["clip_id", "source_uri"]).to_pylist()]
    assert {r["clip_id"] for r in rows} == kept and kept
    assert {r["source_uri"] for r in rows} == {str(inbox / "good_0.mp4"), escaped_name(good)}
    assert lineage_problems(db) == {}
