"""dynamics: monocular video of rigid objects -> executable MuJoCo scene (scene language v1)."""

import os

# Offscreen rendering through EGL (Mesa llvmpipe on CPU machines); must be set before
# mujoco / dm_control are imported anywhere (DESIGN.md §3).
os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

__version__ = "0.1.0"
