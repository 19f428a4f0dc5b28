"""`worldline simulate --controls` and `worldline controls` end to end: files, checks, lineage."""

from typer.testing import CliRunner

from flows.cli import app
from schemas.settings import Settings
from tasks.controls.check import check_controls
from warehouse import audit
from warehouse.store import Warehouse

from tests.support import MANIFESTS, scene_frames, write_video

runner = CliRunner()


def lines(result) -> list[str]:
    return [line for line in result.output.splitlines() if line.strip()]


def query(sql: str) -> list[tuple]:
    with Warehouse(Settings().warehouse_path, read_only=True) as warehouse:
        return warehouse.query(sql)[1]


def test_simulate_controls_then_edges_and_blur_all_in_lineage(prefect_harness, data_root, tmp_path):
    manifest = tmp_path / "closeup.yaml"
    manifest.write_text((MANIFESTS / "push_closeup.yaml").read_text().replace("horizon_s: 6.0", "horizon_s: 1.0"))
    assert runner.invoke(app, ["simulate", str(manifest), "--episodes", "1"]).exit_code == 0
    (episode,) = (data_root / "episodes").glob("*/episode_000000")
    assert not (episode / "controls").exists()
    video_sha = query("SELECT sha256 FROM artifacts WHERE kind = 'episode_video'")

    result = runner.invoke(app, ["simulate", str(manifest), "--episodes", "1", "--controls"])
    assert result.exit_code == 0, result.output
    assert sorted(check_controls(episode, "side")) == ["depth", "seg"]
    # The same seed rendered again: the same video, so the same artifact, now with its controls.
    assert query("SELECT sha256 FROM artifacts WHERE kind = 'episode_video'") == video_sha

    result = runner.invoke(app, ["controls", str(episode)])
    assert result.exit_code == 0 and "1 videos, 1 given controls" in result.output, result.output
    assert sorted(check_controls(episode, "side")) == ["blur", "depth", "edges", "seg"]
    rows = query("SELECT a.attrs->>'control', a.uri, e.relation, v.kind FROM artifacts a "
                 "JOIN edges e ON e.child_id = a.artifact_id JOIN artifacts v ON v.artifact_id = e.parent_id "
                 "WHERE a.kind = 'control' ORDER BY 1")
    assert [(r[0], r[2], r[3]) for r in rows] == [(c, "control_of", "episode_video")
                                                  for c in ("blur", "depth", "edges", "seg")]
    assert all(r[1].startswith("episodes/") and (data_root / r[1]).is_file() for r in rows)
    (depth,) = query("SELECT artifact_id FROM artifacts WHERE attrs->>'control' = 'depth'")
    sql, _ = audit.bind("ancestry", {"artifact": "x"})
    with Warehouse(Settings().warehouse_path, read_only=True) as warehouse:
        chain = warehouse.query(sql, {"artifact": depth[0]})[1]
    assert [r[1] for r in chain] == ["control", "episode_video", "episode", "manifest"]
    again = runner.invoke(app, ["controls", str(episode)])
    assert again.exit_code == 0 and "0 given controls" in again.output
    verified = runner.invoke(app, ["verify", "--format", "json"])
    assert verified.exit_code == 0, verified.output  # every control file has the bytes lineage holds


def test_controls_of_a_clip_under_out_and_refusals(prefect_harness, data_root, tmp_path):
    clip = write_video(tmp_path / "clip one.mp4", scene_frames(3))
    result = runner.invoke(app, ["controls", str(clip), "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["clip one.blur.mp4", "clip one.edges.mp4"]
    kinds = query("SELECT v.kind, count(*) FROM edges e JOIN artifacts v ON v.artifact_id = e.parent_id "
                  "WHERE e.relation = 'control_of' GROUP BY 1")
    assert kinds == [("raw_video", 2)]

    notes = tmp_path / "notes.mp4"
    notes.write_text("not a video\n")
    for args, said in ((["controls", str(notes)], "not a readable video"),
                       (["controls", str(tmp_path / "nothing")], "no such file or folder")):
        refused = runner.invoke(app, args)
        assert refused.exit_code == 2 and len(lines(refused)) == 1 and said in lines(refused)[0], refused.output

    # A folder goes on without its unreadable video: that one named, the rest given controls, exit 1.
    batch = tmp_path / "batch"
    batch.mkdir()
    write_video(batch / "good.mp4", scene_frames(3))
    (batch / "broken.mp4").write_bytes(b"not a video either\n")
    partial = runner.invoke(app, ["controls", str(batch)])
    assert partial.exit_code == 1, partial.output
    assert any("broken.mp4" in line and "not a readable video" in line for line in lines(partial)), partial.output
    assert sorted(p.name for p in batch.iterdir()) == ["broken.mp4", "good.blur.mp4", "good.edges.mp4", "good.mp4"]
    assert "1 not readable, left out" in partial.output
    assert query("SELECT status FROM runs ORDER BY started_at DESC LIMIT 1") == [("partial",)]
    (batch / "good.mp4").unlink()
    (batch / "good.blur.mp4").unlink()
    (batch / "good.edges.mp4").unlink()
    nothing = runner.invoke(app, ["controls", str(batch)])  # nothing readable left: refused whole
    assert nothing.exit_code == 2 and "no readable video there" in nothing.output, nothing.output


def test_controls_write_over_no_file_of_the_users_and_refuse_a_changed_one(prefect_harness, data_root, tmp_path):
    """A user's file under a control's name was replaced without a word, and a control file
    changed after it was written was skipped as done (exit 0)."""
    folder = tmp_path / "videos"
    folder.mkdir()
    for name in ("a", "b"):
        write_video(folder / f"{name}.mp4", scene_frames(3))
    (folder / "a.blur.mp4").write_bytes(b"mine")
    partial = runner.invoke(app, ["controls", str(folder)])
    assert partial.exit_code == 1, partial.output
    assert any(line.startswith(f"{folder / 'a.blur.mp4'}: a file lineage did not record is there")
               for line in lines(partial)), partial.output
    assert (folder / "a.blur.mp4").read_bytes() == b"mine" and not (folder / "a.edges.mp4").exists()
    assert (folder / "b.blur.mp4").is_file() and (folder / "b.edges.mp4").is_file()  # the rest go on
    edges = folder / "b.edges.mp4"
    edges.write_bytes(edges.read_bytes() + b"appended")
    refused = runner.invoke(app, ["controls", str(folder / "b.mp4")])
    assert refused.exit_code == 5 and lines(refused)[-1].startswith(f"{edges}: sha256 "), refused.output


def test_the_flows_take_what_their_parameter_models_hold():
    """As tests/flows/test_param_checks.py holds every other flow: the CLI and a deployment
    (prefect.yaml's controls-inbox) are checked by the same model."""
    import inspect

    from flows.controls import controls
    from flows.params_data import ControlsParams, SimulateParams
    from flows.simulate import simulate

    for flow, model in ((controls, ControlsParams), (simulate, SimulateParams)):
        signature = inspect.signature(flow.fn).parameters
        assert set(signature) == set(model.model_fields)
        assert all(p.default == (inspect.Parameter.empty if model.model_fields[n].is_required()
                                 else model.model_fields[n].default) for n, p in signature.items())
        assert f"{model.__name__}.of(locals())" in inspect.getsource(flow.fn)
