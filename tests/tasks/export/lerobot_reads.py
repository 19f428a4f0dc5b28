"""Run by tests/tasks/export/test_lerobot.py under .venv-lerobot/bin/python (the real `lerobot`
from PyPI; Makefile target lerobot-env): load an export with LeRobotDataset from its folder (no
hub) and iterate it whole through a torch DataLoader, video frames decoded by lerobot's default
decoder (torchcodec). Prints one JSON object: what lerobot read, for the test to compare with the
files. Usage: python lerobot_reads.py DATASET_DIR"""

import json
import sys

import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.datasets.video_utils import get_safe_default_codec


def main(root: str) -> None:
    dataset = LeRobotDataset("worldline/export", root=root)
    loader = torch.utils.data.DataLoader(dataset, batch_size=16, shuffle=False, num_workers=0)
    rows = {"index": [], "episode_index": [], "frame_index": [], "timestamp": [], "task": [],
            "observation.state": [], "action": [], "image_mean": [], "image_first": None}
    shapes, dtypes = {}, {}
    camera = dataset.meta.video_keys[0]
    for batch in loader:
        for key, value in batch.items():
            if isinstance(value, torch.Tensor):
                shapes[key], dtypes[key] = list(value.shape[1:]), str(value.dtype)
        for key in ("index", "episode_index", "frame_index", "timestamp", "observation.state", "action"):
            rows[key].extend(batch[key].tolist())
        rows["task"].extend(batch["task"])
        frames = batch[camera]
        rows["image_mean"].extend(frames.mean(dim=(2, 3)).tolist())
        if rows["image_first"] is None:
            rows["image_first"] = frames[0].tolist()
    print(json.dumps({
        "lerobot": __import__("lerobot").__version__,
        "torch": torch.__version__, "decoder": get_safe_default_codec(), "len": len(dataset),
        "episodes": dataset.num_episodes, "fps": dataset.fps, "camera": camera,
        "video_keys": dataset.meta.video_keys, "tasks": list(dataset.meta.tasks.index),
        "stats": {k: {s: list(torch.as_tensor(v).shape) for s, v in d.items()} for k, d in dataset.meta.stats.items()},
        "shapes": shapes, "dtypes": dtypes, "rows": rows}))


if __name__ == "__main__":
    main(sys.argv[1])
