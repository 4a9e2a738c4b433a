"""Test set-up: offscreen EGL rendering and offline Hugging Face, before anything imports mujoco."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
os.environ.setdefault("TOKENIZERS_PARALLELISM", "false")


def write_model_inputs(root, scenes: list[str], think: str) -> list[str]:
    """The inputs of the tokenize / finetune / predict stages for six scenes, as finished stages
    leave them under ``root``: ``configs`` (splits train x3, val, test, test_comp), ``events``
    (the same think text for each), random ``flow`` (8 frames) and ``video`` (9 RGB frames) of
    32 x 48 px, two shards of three scenes, each folder with its meta.json.

    Returns:
        the scene ids.
    """
    from pathlib import Path

    import numpy as np

    from pipeline import shards

    root = Path(root)
    rng = np.random.default_rng(0)
    ids = [shards.scene_id(i) for i in range(6)]
    splits = ["train", "train", "train", "val", "test", "test_comp"]
    for s in range(2):  # two shards of three scenes
        part = slice(3 * s, 3 * s + 3)
        shards.write_table(shards.shard_path(root / "configs", s, "parquet"), [
            {"scene_id": i, "split": sp, "seed": 0, "scene": sc, "composition": "sphere"}
            for i, sp, sc in zip(ids[part], splits[part], scenes[part])])
        shards.write_arrays(shards.shard_path(root / "flow", s, "zarr"),
                            {"flow": rng.normal(size=(3, 8, 32, 48, 2)).astype(np.float16)},
                            scene_ids=ids[part], attrs={"max_magnitude": 2.0})
        shards.write_arrays(shards.shard_path(root / "video", s, "zarr"),
                            {"rgb": rng.integers(0, 256, (3, 9, 32, 48, 3), dtype=np.uint8)},
                            scene_ids=ids[part])
    shards.write_table(shards.shard_path(root / "events", 0, "parquet", prefix="think"),
                       [{"scene_id": i, "think": think} for i in ids])
    for name in ("configs", "flow", "video", "events"):  # finished stages leave a meta.json
        shards.write_meta(root / name, {})
    return ids


def moving_disc_avi(path, n: int = 60):
    """Write an MJPG avi of ``n`` frames, 96 x 64 px at 30 fps, a green disc moving right 1 px per
    frame on grey (a small, exactly countable video to cut and damage). Returns ``path``."""
    import cv2
    import numpy as np

    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (96, 64))
    for k in range(n):
        frame = np.full((64, 96, 3), 90, np.uint8)
        cv2.circle(frame, (10 + k, 32), 8, (40, 200, 40), -1)
        writer.write(frame)
    writer.release()
    return path


def still_textured_mp4(path, width: int = 320, height: int = 240, n: int = 45):
    """Write an mp4 of ``n`` identical frames at 30 fps: a smooth random texture (seed 0) in which
    nothing moves and nothing stands out (a still shot: no object to observe). Returns ``path``."""
    import cv2
    import numpy as np

    rng = np.random.default_rng(0)
    still = cv2.GaussianBlur(rng.integers(60, 200, (height, width, 3), dtype=np.uint8), (0, 0), 3)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30, (width, height))
    for _ in range(n):
        writer.write(still)
    writer.release()
    return path
