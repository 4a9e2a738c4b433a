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


# ----------------------------------------------------------------------------- rendered clips (issue 30)
def _clip(T: int = 12, H: int = 48, W: int = 64) -> np.ndarray:
    """A grey clip (128) with a white vertical bar: a flat field and a sharp edge."""
    rgb = np.full((T, H, W, 3), 128, np.uint8)
    rgb[:, :, 40:48] = 250
    return rgb


def test_camera_effects_repeat_with_the_seed_and_keep_shape_and_dtype():
    rgb = _clip()
    a = R.camera_effects(rgb, np.random.default_rng(3))
    b = R.camera_effects(rgb, np.random.default_rng(3))
    c = R.camera_effects(rgb, np.random.default_rng(4))
    assert a.shape == rgb.shape and a.dtype == np.uint8
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    np.testing.assert_array_equal(rgb, _clip())                    # the input is not changed
    import pytest
    with pytest.raises(ValueError, match=r"\(T, H, W, 3\) uint8"):
        R.camera_effects(rgb.astype(np.float32), np.random.default_rng(0))


def test_camera_effects_stay_within_their_stated_ranges():
    """Over many clips: the flat field's mean stays within the exposure gain range, its noise within
    the sensor noise range (+ JPEG), the noise is fresh in every frame, and blur never sharpens."""
    rgb = _clip()
    lo_gain, hi_gain = R.CAMERA_GAIN
    edge0 = np.abs(np.diff(rgb[0, 24, :, 0].astype(float))).max()
    blurred = fresh = 0
    for seed in range(30):
        out = R.camera_effects(rgb, np.random.default_rng(seed)).astype(np.float64)
        flat = out[:, 8:40, 4:32]                                  # away from the bar
        assert lo_gain * 128 - 3 <= flat[-1].mean() <= hi_gain * 128 + 3
        assert abs(flat[0].mean() - 128) <= 3                      # the drift starts at gain 1
        # frame-to-frame difference of the first two frames (gain ~1 there): sqrt(2) x the noise
        sd = np.std(flat[1] - flat[0]) / np.sqrt(2)
        assert sd <= R.CAMERA_NOISE_STD[1] + 3.0, sd
        fresh += sd >= 0.3                                         # (strong JPEG can flatten weak noise)
        edge = np.abs(np.diff(out[0, 24, :, 0])).max()
        assert edge <= edge0 * 1.15 + 3 * R.CAMERA_NOISE_STD[1]
        blurred += edge < 0.7 * edge0
    assert 5 <= blurred <= 28                                      # blur on some clips, not on all
    assert fresh >= 20
