"""corpus: a reproducible labelled raw-footage corpus (simulator and procedural segments)."""

from __future__ import annotations

from prefect import flow, task

from flows.params import Fps, Height, Minutes, Seed, Width
from flows.params_data import CorpusParams
from flows.recording import recorded_run
from flows.report import markdown_table, progress, publish
from schemas import paths
from schemas.hashing import stable_id
from schemas.settings import Settings
from tasks import progress as ticks
from tasks.corpus import generate
from tasks.lookup import recorded_files

generate_corpus = task(generate.generate_corpus, name="generate-corpus", retries=1)


@flow(name="corpus", log_prints=True)
def corpus(minutes: Minutes = 1.0, seed: Seed = 0, width: Width = 640, height: Height = 360, fps: Fps = 30.0) -> dict:
    """Raw videos with a ground-truth JSON beside each, under <data_root>/corpus/seed_<seed>."""
    CorpusParams.of(locals())  # every parameter check, for a deployment as for the CLI
    settings = Settings()
    params = {"minutes": minutes, "seed": seed, "width": width, "height": height, "fps": fps}
    with recorded_run("corpus", settings, params=params) as run:
        root = settings.data_root
        folder = paths.resolve(root, paths.CORPUS_VIDEO, seed=seed, index=0).parent
        stage = run.stage("corpus", stable_id("corpus", *(f"{k}={v}" for k, v in sorted(params.items()))),
                          manifest_hash=None)
        if stage.done and (made := sorted(folder.glob("raw_*.mp4"))):  # made before with these settings
            print(f"corpus seed {seed}: {len(made)} videos, made before with these settings")
            return {"videos": [str(v) for v in made], "seed": seed}
        generate.check_folder(folder, lambda held: recorded_files(run.warehouse, root, held))  # nor the user's
        with progress(round(minutes * 60 * fps), f"corpus seed {seed} (frames)", topic=ticks.CORPUS_FRAMES):
            videos = generate_corpus(root, seed=seed, minutes=minutes, width=width, height=height, fps=fps)
        stage.finish(0, len(videos), generate.corpus_lineage(videos, stage.id, None, root), attrs=params)
        print(f"corpus seed {seed}: {len(videos)} videos, {minutes} min at {width}x{height}")
        publish("corpus", f"seed {seed}, {len(videos)} videos, {minutes} min at {width}x{height}",
                markdown_table(("video", "ground truth"), [(v.video.name, v.truth.name) for v in videos]),
                "generated raw footage with ground truth")
        return {"videos": [str(v.video) for v in videos], "seed": seed}
