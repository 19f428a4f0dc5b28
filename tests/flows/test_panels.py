"""The panels flow on a tiny grid: variants, episodes, contact sheet, video, guards, lineage."""

from pathlib import Path

import av
import torch
from PIL import Image

from flows.panels import panels
from schemas.settings import Settings
from warehouse import audit
from warehouse.store import Warehouse

from tests.support import MANIFESTS

GRID = """
name: tiny
cells:
  - name: nominal
  - name: clean
    drop: [appearance, distractors]
  - name: dim
    stressors: [{kind: dim_light, lux: 60}]
episodes: 2
"""


def _tiny(tmp_path: Path) -> tuple[Path, Path]:
    text = (MANIFESTS / "conveyor_push.yaml").read_text()
    manifest = tmp_path / "push.yaml"
    manifest.write_text(text.replace("horizon_s: 5.0", "horizon_s: 1.0").replace("[128, 128]", "[64, 64]"))
    grid = tmp_path / "grid.yaml"
    grid.write_text(GRID)
    return manifest, grid


def test_panel_writes_sheet_video_and_lineage_and_a_rerun_adds_nothing(prefect_harness, data_root, tmp_path):
    manifest, grid = _tiny(tmp_path)
    result = panels(str(manifest), str(grid))
    sheet = Image.open(data_root / result["contact_sheet"])
    # header (28 px) + 3 rows of 64 px (+2 px gaps); label column 120 px + 6 samples of 64 px (+2)
    assert sheet.size == (120 + 6 * 66, 28 + 3 * 66)
    with av.open(str(data_root / result["video"])) as video:
        frames = [f.to_ndarray(format="rgb24") for f in video.decode(video=0)]
    assert len(frames) == 30 and frames[0].shape == (2 * (64 + 14 + 2), 2 * (64 + 2), 3)
    # The dim cell is darker than the nominal one in the same frame of the video.
    nominal, dim = frames[10][14:78, :64], frames[10][14 + 80:78 + 80, :64]
    assert dim.mean() < 0.6 * nominal.mean()
    assert [v["cell"] for v in result["variants"]] == ["nominal", "clean", "dim"]
    assert all(len(v["episodes"]) == 2 for v in result["variants"])

    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, variants = wh.query("SELECT manifest_hash, parent_hash FROM manifests WHERE parent_hash IS NOT NULL")
        _, kinds = wh.query("SELECT kind, count(*) FROM artifacts GROUP BY kind ORDER BY kind")
        _, edges = wh.query("SELECT relation, count(*) FROM edges WHERE child_id = $p GROUP BY relation ORDER BY relation",
                            {"p": result["panel_id"]})
        _, text = wh.query("SELECT subject_id, value FROM metrics WHERE name = 'guard_text_matches'")
        _, faces = wh.query("SELECT m.value, a.attrs->>'role' FROM metrics m JOIN artifacts a ON a.artifact_id = m.subject_id "
                            "WHERE m.name = 'guard_faces_frames' ORDER BY 2")
        sql, _ = audit.bind("ancestry", {"artifact": "x"})
        _, chain = wh.query(sql, {"artifact": result["panel_id"]})
        counts = wh.counts()
    assert len(variants) == 3 and {p for _, p in variants} == {result["manifest_hash"]}
    assert dict(kinds) == {"episode": 6, "episode_video": 6, "manifest": 4, "panel": 3}
    assert dict(edges) == {"panel_episode": 6, "panel_variant": 3}
    assert len(text) == 4 and all(v == 0 for _, v in text)  # 3 variants and the grid, all clean
    assert [role for _, role in faces] == ["contact_sheet", "video"] and all(v == 0 for v, _ in faces)
    ancestors = {r[1] for r in chain}
    assert {"episode", "manifest"} <= ancestors and result["manifest_hash"] in {r[2] for r in chain}

    again = panels(str(manifest), str(grid))
    assert again["panel_id"] == result["panel_id"]
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        after = wh.counts()
    assert {k: v for k, v in after.items() if k != "runs"} == {k: v for k, v in counts.items() if k != "runs"}


def test_cli_refuses_a_bad_grid_with_one_line(data_root, tmp_path):
    from typer.testing import CliRunner

    from flows.cli import app

    manifest, grid = _tiny(tmp_path)
    grid.write_text("name: g\ncells:\n  - name: Bad Name\n")
    result = CliRunner().invoke(app, ["panels", str(manifest), "--grid", str(grid)])
    assert result.exit_code == 2 and "cells.0.name" in result.output and str(grid) in result.output
    assert not (data_root / "lineage.duckdb").exists()


def random_world_model(folder: Path, size: int = 32) -> Path:
    """An untrained tiny tokenizer and action-conditioned world model, saved as flows/train.py
    saves them: the plumbing under test, not the skill."""
    from models.tokenizer import VideoTokenizer
    from models.tokenizer import preset as tokenizer_preset
    from models.world_model import WorldModel, preset
    from tasks.tokenize.tokens import save_checkpoint as save_tokenizer
    from tasks.world.checkpoints import save_checkpoint

    torch.manual_seed(0)
    tokenizer = VideoTokenizer(tokenizer_preset("tiny-dv4x8x8"))
    save_tokenizer(tokenizer, folder / "tok")
    c = tokenizer.config
    model = WorldModel(preset("tiny-wm", codebook_size=c.codebook_size, temporal_compression=c.temporal_compression,
                              max_height=size // 8, max_width=size // 8)).add_action_conditioning()
    save_checkpoint(model, folder / "wm", {"tokenizer": str(folder / "tok"), "size": size})
    return folder / "wm"


def test_world_model_rollouts_sit_beside_the_simulator(prefect_harness, data_root, tmp_path):
    manifest, grid = _tiny(tmp_path)
    grid.write_text("name: one\ncells:\n  - name: nominal\nepisodes: 1\n")
    result = panels(str(manifest), str(grid), world_model=str(random_world_model(tmp_path)))
    sheet = Image.open(data_root / result["contact_sheet"])
    assert sheet.size == (120 + 6 * (2 * 64 + 2 + 2), 28 + 66)  # each sample: simulator | world model
    with Warehouse(Settings().warehouse_path, read_only=True) as wh:
        _, attrs = wh.query("SELECT attrs->>'world_model' FROM artifacts WHERE artifact_id = $p",
                            {"p": result["panel_id"]})
        _, faces = wh.query("SELECT count(*) FROM metrics WHERE name = 'guard_faces_frames'")
    assert attrs[0][0].endswith("wm") and faces[0][0] == 3  # the sheet, the video and the world model's rollout


def test_world_model_verdicts_come_from_generated_frames(prefect_harness, data_root, tmp_path):
    import json

    from flows.evaluate import evaluate

    manifest, grid = _tiny(tmp_path)
    grid.write_text("name: one\ncells:\n  - name: nominal\nepisodes: 1\n")
    result = evaluate(str(manifest), str(grid), policies=["scripted"],
                               world_model=str(random_world_model(tmp_path)))
    (evaluation,) = result["evaluations"]
    body = json.loads((data_root / "evaluations" / evaluation["evaluation_id"] / "result.json").read_text())
    # An untrained model generates noise; what matters is that the detector judged its frames.
    (episode,) = body["episodes"]
    assert episode["world"] in (None, True, False) and "in the frames" in episode["world_reason"] or \
        episode["world_reason"].startswith(("goal marker not found", "package seen in only"))
    assert body["world_model"].endswith("wm")


def test_a_reused_episode_whose_files_changed_is_refused(prefect_harness, data_root, tmp_path):
    import pytest

    from schemas.errors import TamperedArtifact

    manifest, grid = _tiny(tmp_path)
    grid.write_text(GRID.replace("episodes: 2", "episodes: 1"))
    panels(str(manifest), str(grid))
    video = sorted((data_root / "episodes").rglob("*.mp4"))[0]
    data = bytearray(video.read_bytes())
    data[len(data) // 2] ^= 0xFF
    video.write_bytes(bytes(data))
    with pytest.raises(TamperedArtifact, match=rf"^{video}: sha256 \w+ differs from lineage's"):
        panels(str(manifest), str(grid))


def test_a_reused_episode_with_another_episodes_video_is_refused(prefect_harness, data_root, tmp_path):
    """The nominal cell's episodes are byte for byte the manifest's own, and lineage records a
    video by its bytes: at the cell's path there is no row of its own, so episode 0's video
    copied over episode 1's matched episode 0's row and the panel used it without a word."""
    import filecmp
    import shutil

    import pytest

    from flows.simulate import simulate
    from schemas.errors import TamperedArtifact

    manifest, grid = _tiny(tmp_path)
    own = simulate(str(manifest), 2)["manifest_hash"][:12]
    panels(str(manifest), str(grid))
    twins = [f for f in sorted((data_root / "episodes").iterdir()) if f.name != own and filecmp.cmp(
        f / "episode_000000" / "overhead.mp4", data_root / "episodes" / own / "episode_000000" / "overhead.mp4",
        shallow=False)]
    assert len(twins) == 1  # the nominal cell's folder
    first, second = (twins[0] / f"episode_00000{i}" / "overhead.mp4" for i in (0, 1))
    shutil.copyfile(first, second)
    with pytest.raises(TamperedArtifact, match=rf"^{second}: sha256 \w+ is not a video lineage recorded for this episode"):
        panels(str(manifest), str(grid))
