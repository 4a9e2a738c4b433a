"""dynamics: monocular video of rigid objects -> executable MuJoCo scene (scene language v1)."""

import os

# Offscreen rendering through EGL (Mesa llvmpipe on CPU machines); must be set before
# mujoco / dm_control are imported anywhere (docs/design.md §3).
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])
# FFmpeg's own log lines ("moov atom not found", "error while decoding MB ...") would follow our
# one-line errors on stderr; OpenCV passes this level to av_log_set_level (-8 = quiet). Problems
# still surface as pipeline.video.VideoError.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")

__version__ = "0.1.0"

if os.environ.get("DVC_STAGE"):
    # a stage script run by `dvc repro` ends when dvc dies (kill -9 of dvc), see pipeline.stage_watchdog
    from pipeline.stage_watchdog import exit_with_parent

    exit_with_parent()
