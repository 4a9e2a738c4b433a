"""The segmenter's training realism (issue 36): scenery is background, an occluder hides what it
covers, zoom-out keeps inputs and targets aligned, camera noise only adds to the difference."""

import numpy as np

from pipeline import frame_realism as R


def _batch(B: int = 6, H: int = 120, W: int = 160):
    """A grey floor with one bright square object (diff 0.5 on it), its targets."""
    x = np.zeros((B, 4, H, W), np.float32)
    y = np.zeros((B, 2, H, W), np.float32)
    x[:, :3, 50:70, 70:90] = 0.4
    x[:, 3, 50:70, 70:90] = 0.5
    y[:, 0, 50:70, 70:90] = 1.0
    return x, y


def test_scenery_behind_objects_is_background_and_leaves_the_object_alone():
    x, y = _batch()
    x0, y0 = x.copy(), y.copy()
    R.P_IN_FRONT, keep = 0.0, R.P_IN_FRONT
    try:
        R.draw_scenery(x, y, np.random.default_rng(0), p=1.0)
    finally:
        R.P_IN_FRONT = keep
    obj = y0[:, 0] > 0.5
    np.testing.assert_array_equal(y, y0)                          # targets unchanged
    for b in range(len(x)):
        np.testing.assert_array_equal(x[b][:, obj[b]], x0[b][:, obj[b]])
    changed = (x != x0).any(axis=1)
    assert changed.any(axis=(1, 2)).all()                        # every image got scenery
    assert (x[:, 3][changed] < 0.06).all()                        # static: ~0 difference to the background


def test_scenery_in_front_clears_the_targets_it_covers():
    x, y = _batch(B=40)
    R.P_IN_FRONT, keep = 1.0, R.P_IN_FRONT
    try:
        R.draw_scenery(x, y, np.random.default_rng(1), p=1.0)
    finally:
        R.P_IN_FRONT = keep
    covered = (x[:, :3, 50:70, 70:90] != 0.4).any(axis=1)
    assert covered.any()                                          # some occluder crossed the object
    assert (y[:, 0, 50:70, 70:90][covered] == 0).all()
    assert (y[:, 0, 50:70, 70:90][~covered] == 1).all()


def test_zoom_out_shrinks_inputs_and_targets_alike():
    x, y = _batch(B=4)
    R.zoom_out(x, y, np.random.default_rng(2), p=1.0, factor=(2.0, 2.0))
    for b in range(len(x)):
        obj_in = x[b, 3] > 0.25
        obj_t = y[b, 0] > 0.5
        assert (obj_in == obj_t).mean() > 0.995
        # the square's 400 px shrink by 2 x 2; reflected copies are whole or cut by the border
        n, _, stats, _ = __import__("cv2").connectedComponentsWithStats(obj_t.astype(np.uint8))
        assert stats[1:, 4].max() <= 110


def test_camera_noise_only_raises_the_difference_and_keeps_targets():
    x, y = _batch()
    x0, y0 = x.copy(), y.copy()
    R.camera_noise(x, np.random.default_rng(3), p=1.0)
    np.testing.assert_array_equal(y, y0)
    assert (x[:, 3] >= x0[:, 3]).all()
    assert np.abs(x[:, :3]).max() <= 0.5 + 1e-6
