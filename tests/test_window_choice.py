"""The automatic window (``pipeline.observe.choose_window`` / ``observe``): large objects that cross
the view early are not lost to the penalty meant for hands."""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest

from pipeline.observe import choose_window, observe
from pipeline.video import VideoWarning

W, H, FPS = 320, 240, 30


def _clip(path, frames: int = 60, crossing: int = 15) -> None:
    """A textured still background; two discs of 40 px radius (5 % of the frame each, above
    ``MAX_MOVING_FRACTION``) cross the view left to right in the first ``crossing`` frames and
    leave; then nothing moves."""
    rng = np.random.default_rng(0)
    bg = cv2.GaussianBlur(rng.integers(80, 180, (H, W, 3), dtype=np.uint8), (0, 0), 3)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), FPS, (W, H))
    for t in range(frames):
        f = bg.copy()
        if t < crossing:
            x = int(-40 + (W + 80) * t / (crossing - 1))
            cv2.circle(f, (x, 80), 40, (30, 40, 200), -1)
            cv2.circle(f, (W - x, 170), 40, (200, 60, 30), -1)
        writer.write(f)
    writer.release()


def test_large_objects_score_as_hands_in_the_first_choice_of_window(tmp_path):
    """Every frame with the discs moves more than ``MAX_MOVING_FRACTION`` of the image: the first
    choice (the most object-sized motion) starts after their last frame in view (frame 13: at
    frame 14 both are past the border); without the penalty the window starts where they move."""
    video = tmp_path / "crossing.mp4"
    _clip(video)
    first, _ = choose_window(video, None, FPS, 1.0)
    any_size, _ = choose_window(video, None, FPS, 1.0, large_motion_penalty=False)
    assert round(first * FPS) >= 14 and any_size == 0.0


@pytest.mark.parametrize("mask_method", ["median", "hybrid"])
def test_a_window_that_shows_nothing_is_tried_again_where_the_motion_is(tmp_path, mask_method):
    """``observe`` without a start: the first window shows nothing, so it is observed again from
    the start with the most motion of any size (with a warning), where both discs are found and
    move; the observation still says the window was chosen automatically."""
    video = tmp_path / "crossing.mp4"
    _clip(video)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        obs = observe(video, None, None, FPS, 1.0, mask_method=mask_method)
    assert obs.auto and obs.start == 0.0
    assert int(obs.seg.max()) + 1 == 2, "both discs"
    assert any(issubclass(w.category, VideoWarning) and "nothing seen" in str(w.message) for w in caught)
    # an explicit start is taken as given, even where nothing is seen
    late = observe(video, None, 1.0, FPS, 0.9, mask_method=mask_method)
    assert not late.auto and not (late.seg >= 0).any()
