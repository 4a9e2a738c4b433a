"""Tests for pipeline.metrics and pipeline.scene_metrics on hand-made masks and flows whose values are
computed by hand."""

import math

import numpy as np
import pytest

from pipeline.metrics import flow_epe, mask_iou, match_objects, observation_scores, sequence_iou
from pipeline.scene_metrics import (
    composition_accuracy, markdown_table, match_by_position, parameter_errors, scene_report, summarize,
)
from pipeline.scene import Scene


def _seg(*frames: list[str]) -> np.ndarray:
    """(T, H, W) int8 from ASCII frames: '.' background, digits object ids."""
    return np.array([[[-1 if c == "." else int(c) for c in row] for row in f] for f in frames], dtype=np.int8)


# ------------------------------------------------------------------------------------ mask_iou
def test_mask_iou_by_hand():
    a = np.zeros((4, 4), bool)
    b = np.zeros((4, 4), bool)
    a[0, :4] = True          # 4 px
    b[0, 2:] = True          # 2 px, both inside a
    b[1, 2:] = True          # +2 px outside a
    # intersection 2, union 4 + 4 - 2 = 6
    assert mask_iou(a, b) == pytest.approx(2 / 6)
    assert mask_iou(a, a) == 1.0
    assert mask_iou(a, np.zeros_like(a)) == 0.0


def test_mask_iou_both_empty_is_one():
    z = np.zeros((3, 5), bool)
    assert mask_iou(z, z) == 1.0


def test_mask_iou_shape_mismatch():
    with pytest.raises(ValueError, match="shapes"):
        mask_iou(np.zeros((2, 2), bool), np.zeros((2, 3), bool))


# ------------------------------------------------------------------------------ sequence_iou
TRUE = _seg(
    ["00..", "00..", "..11", "..11"],
    ["00..", "00..", "..11", "..11"],
)


def test_permuted_ids_match_and_score_one():
    pred = np.where(TRUE >= 0, 1 - TRUE, -1).astype(np.int8)  # ids 0 <-> 1 swapped
    assert match_objects(TRUE, pred) == [(0, 1), (1, 0)]
    res = sequence_iou(TRUE, pred)
    assert res["initial_iou"] == 1.0 and res["full_iou"] == 1.0
    np.testing.assert_array_equal(res["per_frame"], [1.0, 1.0])


def test_sequence_iou_by_hand():
    pred = _seg(
        ["00..", "00..", "..11", "..11"],   # frame 0: both exact -> 1.0
        ["0...", "0...", "..11", "...."],   # frame 1: obj0 2/4, obj1 2/4 -> 0.5
    )
    res = sequence_iou(TRUE, pred)
    assert res["initial_iou"] == pytest.approx(1.0)
    np.testing.assert_allclose(res["per_frame"], [1.0, 0.5])
    assert res["full_iou"] == pytest.approx(0.75)
    # foreground: frame 1 union 8, intersection 4 -> 0.5
    assert res["foreground_iou_initial"] == pytest.approx(1.0)
    assert res["foreground_iou_full"] == pytest.approx(0.75)


def test_unmatched_true_object_counts_zero():
    pred = np.where(TRUE == 1, 0, -1).astype(np.int8)  # only object 1 predicted, as id 0
    assert match_objects(TRUE, pred) == [(1, 0)]
    res = sequence_iou(TRUE, pred)
    assert res["full_iou"] == pytest.approx(0.5)          # (0 + 1) / 2 true objects
    assert res["foreground_iou_full"] == pytest.approx(0.5)  # 4 of 8 px


def test_extra_predicted_object_does_not_count_in_average():
    pred = _seg(["00.2", "00..", "..11", "..11"], ["00.2", "00..", "..11", "..11"])
    res = sequence_iou(TRUE, pred)
    assert res["full_iou"] == 1.0 and res["n_pred"] == 3
    assert res["foreground_iou_full"] == pytest.approx(8 / 9)


def test_matching_uses_mean_over_sequence():
    # frame 0 alone would match pred 0 (IoU 1 vs 0); over the sequence pred 1 wins (2/3 vs 1/3)
    true = _seg(["00..", "...."], ["00..", "...."], ["00..", "...."])
    pred = _seg(["00..", "...."], ["11..", "..00"], ["11..", "..00"])
    assert match_objects(true, pred) == [(0, 1)]
    res = sequence_iou(true, pred)
    np.testing.assert_allclose(res["per_frame"], [0.0, 1.0, 1.0])
    assert res["full_iou"] == pytest.approx(2 / 3)


def test_bool_masks_are_one_object():
    fg = TRUE >= 0
    res = sequence_iou(fg, fg)
    assert res["n_true"] == 1 and res["full_iou"] == 1.0


def test_strict_iou_gives_no_credit_for_agreeing_on_absence():
    # object 0 is seen in frame 0 only, object 1 in all four; the prediction has object 1 exact
    # and never shows an object 0 (label 0 empty in every frame).
    true = _seg(["0...", "..11"], ["....", "..11"], ["....", "..11"], ["....", "..11"])
    pred = np.where(true == 1, 1, -1).astype(np.int8)
    res = sequence_iou(true, pred)
    # design §7: object 0 matches the empty label 0 and scores 1.0 in the 3 frames where both are
    # absent: (0 + 1 + 1 + 1) / 4 = 0.75, so full = (0.75 + 1) / 2
    assert res["full_iou"] == pytest.approx(0.875)
    # strict (issue 29 item 7): object 0 is missed (0), object 1 exact (1)
    assert res["strict_iou"] == pytest.approx(0.5)
    assert res["n_true_visible"] == 2 and res["n_pred_visible"] == 1
    # with object 0 found in its one frame, both agree on a perfect score
    assert sequence_iou(true, true)["strict_iou"] == 1.0


def test_strict_iou_nothing_observed_is_undefined_not_perfect():
    empty = np.full((3, 2, 4), -1, np.int8)
    res = sequence_iou(empty, empty)
    assert res["full_iou"] == 1.0                    # the docs/design.md §7 convention
    assert math.isnan(res["strict_iou"]) and res["n_true_visible"] == 0


def test_strict_iou_equals_the_observation_score():
    rng = np.random.default_rng(3)
    for _ in range(20):
        true = rng.integers(-1, 3, (5, 6, 7)).astype(np.int8)
        true[2:][true[2:] == 1] = -1                 # object 1 leaves after frame 1
        pred = rng.integers(-1, 2, (5, 6, 7)).astype(np.int8)
        assert sequence_iou(true, pred)["strict_iou"] == pytest.approx(observation_scores(true, pred)["matched_iou"])


def test_sequence_iou_rejects_bad_input():
    with pytest.raises(ValueError, match="equal shapes"):
        sequence_iou(TRUE, TRUE[:1])
    with pytest.raises(ValueError, match="labels must be >= -1"):
        sequence_iou(TRUE, TRUE - 2)
    with pytest.raises(ValueError, match=r"\(T, H, W\)"):
        sequence_iou(TRUE[0], TRUE[0])


# ---------------------------------------------------------------------------------- flow_epe
def test_flow_epe_constant_flows():
    T, H, W = 3, 4, 5
    pred = np.zeros((T, H, W, 2), np.float32)
    obs = np.zeros((T, H, W, 2), np.float16)
    pred[..., 0], pred[..., 1] = 3.0, 4.0          # |(3, 4) - 0| = 5 px everywhere
    fg = np.zeros((T, H, W), bool)
    fg[:, :2, :2] = True
    assert flow_epe(pred, obs, fg, fg) == pytest.approx(5.0)
    # union of masks: pixels only in obs count too, same constant error
    fg_obs = np.zeros_like(fg)
    fg_obs[:, 3, 4] = True
    assert flow_epe(pred, obs, fg, fg_obs) == pytest.approx(5.0)


def test_flow_epe_only_foreground_counts():
    pred = np.zeros((1, 2, 2, 2))
    obs = np.zeros((1, 2, 2, 2))
    obs[0, 0, 0] = (1.0, 0.0)      # foreground pixel: error 1
    obs[0, 1, 1] = (100.0, 0.0)    # background in both: ignored
    fg = np.array([[[True, True], [False, False]]])
    assert flow_epe(pred, obs, fg, np.zeros_like(fg)) == pytest.approx(0.5)  # (1 + 0) / 2


def test_flow_epe_over_the_observed_foreground():
    # observed: 2 px moving at (3, 4) px/frame; predicted: absent there, a still 6 px object elsewhere
    pred = np.zeros((1, 3, 4, 2))
    obs = np.zeros((1, 3, 4, 2))
    fg_obs = np.zeros((1, 3, 4), bool)
    fg_obs[0, 0, :2] = True
    obs[0, 0, :2] = (3.0, 4.0)
    fg_pred = np.zeros_like(fg_obs)
    fg_pred[0, 1:, 1:] = True
    # union: (5 + 5 + 6 x 0) / 8; the still object far away lowers the mean
    assert flow_epe(pred, obs, fg_pred, fg_obs) == pytest.approx(10 / 8)
    # observed: the motion left unexplained, whatever is predicted elsewhere
    assert flow_epe(pred, obs, fg_pred, fg_obs, over="observed") == pytest.approx(5.0)
    assert flow_epe(pred, obs, np.zeros_like(fg_obs), fg_obs, over="observed") == pytest.approx(5.0)
    with pytest.raises(ValueError, match="over"):
        flow_epe(pred, obs, fg_pred, fg_obs, over="both")


def test_flow_epe_no_foreground_is_zero():
    z = np.zeros((2, 3, 3, 2))
    m = np.zeros((2, 3, 3), bool)
    assert flow_epe(z + 1, z, m, m) == 0.0


def test_flow_epe_shape_errors():
    with pytest.raises(ValueError, match="flows"):
        flow_epe(np.zeros((1, 2, 2, 2)), np.zeros((1, 2, 3, 2)), np.zeros((1, 2, 2), bool), np.zeros((1, 2, 2), bool))
    with pytest.raises(ValueError, match="masks"):
        flow_epe(np.zeros((1, 2, 2, 2)), np.zeros((1, 2, 2, 2)), np.zeros((2, 2), bool), np.zeros((1, 2, 2), bool))


# ---------------------------------------------------------------------------- scene metrics
def _scene(objs, **cam) -> Scene:
    camera = {"height": 1.2, "pitch": 35.0, "fov": 45.0, **cam}
    return Scene.from_dict({"camera": camera, "objects": objs})


SPHERE = {"shape": "sphere", "size": {"radius": 0.1}, "mass": 0.5, "position": [0.0, 0.0, 0.1]}
BOX = {"shape": "box", "size": {"width": 0.2, "depth": 0.1, "height": 0.1}, "mass": 1.0, "position": [0.5, 0.0, 0.05]}


def test_composition_accuracy():
    a = _scene([SPHERE, BOX])
    b = _scene([BOX, SPHERE])                 # same multiset, other order
    c = _scene([SPHERE, SPHERE])
    assert composition_accuracy([a, a, a, a], [b, c, None, a]) == pytest.approx(0.5)
    assert math.isnan(composition_accuracy([], []))
    with pytest.raises(ValueError):
        composition_accuracy([a], [])


def test_parameter_errors_by_position_matching():
    true = _scene([SPHERE, BOX])
    pred = _scene([{**BOX, "position": [0.5, 0.03, 0.05], "mass": 1.5},
                   {**SPHERE, "position": [0.0, 0.0, 0.14], "size": {"radius": 0.12}}],
                  height=1.5, fov=40.0)
    assert match_by_position(true, pred) == [(0, 1), (1, 0)]
    err = parameter_errors(true, pred)
    assert err["n_matched"] == 2
    assert err["position"] == pytest.approx((0.04 + 0.03) / 2)
    assert err["mass"] == pytest.approx((0.0 + 0.5) / 2)
    assert err["size"] == pytest.approx((0.04 + 0.0) / 2)         # sphere extents 0.2 -> 0.24
    assert err["camera_position"] == pytest.approx(0.3)
    assert err["camera_fov"] == pytest.approx(5.0)
    assert err["orientation"] == pytest.approx(0.0)


def test_parameter_errors_same_shape_only_and_masks():
    true = _scene([SPHERE, BOX])
    pred = _scene([SPHERE])
    err = parameter_errors(true, pred)
    assert err["n_matched"] == 1 and err["position"] == 0.0
    # with masks: true object 1 is seen where pred object 0 is -> matched across shapes
    true_seg = _seg(["0.1", "..."])
    pred_seg = _seg(["..0", "..."])
    err = parameter_errors(true, pred, true_seg, pred_seg)
    assert err["matches"] == [(1, 0)]
    assert err["position"] == pytest.approx(np.linalg.norm([0.5, 0.0, -0.05]))


def test_orientation_error_in_degrees():
    q90 = [np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)]  # 90 deg about z
    true = _scene([BOX])
    pred = _scene([{**BOX, "orientation": q90}])
    assert parameter_errors(true, pred)["orientation"] == pytest.approx(90.0, abs=1e-6)
    neg = _scene([{**BOX, "orientation": [-1.0, 0.0, 0.0, 0.0]}])   # q and -q: same rotation
    assert parameter_errors(true, neg)["orientation"] == pytest.approx(0.0, abs=1e-6)


def test_scene_report_and_summarize():
    true = _scene([SPHERE])
    seg = _seg(["00.", "..."], ["00.", "..."])
    flow = np.zeros((1, 2, 3, 2), np.float32)
    good = scene_report(true, true, seg, flow, seg, flow + 1.0)   # EPE sqrt(2)
    bad = scene_report(true, None, seg, flow, None, None)
    assert good["valid"] and good["composition_correct"] and good["full_iou"] == 1.0
    assert good["epe"] == pytest.approx(math.sqrt(2))
    assert not bad["valid"] and bad["full_iou"] == 0.0 and math.isnan(bad["epe"])
    s = summarize([good, bad])
    assert s["n"] == 2 and s["n_valid"] == 1
    assert s["composition_accuracy"] == 0.5 and s["full_iou"] == 0.5
    assert s["epe"] == pytest.approx(math.sqrt(2))                  # invalid rows left out
    assert s["parameter_errors"]["position"] == 0.0


def test_summarize_bootstrap_intervals_cover_the_mean_and_shrink_with_n():
    """ci95 of a 0/1 metric (composition hits at rate 0.5) is the binomial spread: about
    +-1.96 * sqrt(0.25 / n); a constant metric has the mean as its interval; the table prints it."""
    true = _scene([SPHERE])
    seg = _seg(["00.", "..."], ["00.", "..."])
    flow = np.zeros((1, 2, 3, 2), np.float32)
    good, bad = scene_report(true, true, seg, flow, seg, flow), scene_report(true, None, seg, flow, None, None)
    widths = {}
    for n in (40, 400):
        s = summarize([good, bad] * (n // 2))
        lo, hi = s["ci95"]["composition_accuracy"]
        assert lo < s["composition_accuracy"] == 0.5 < hi
        widths[n] = hi - lo
        assert widths[n] == pytest.approx(2 * 1.96 * math.sqrt(0.25 / n), rel=0.25)
        assert s["ci95"]["epe"] == [0.0, 0.0]            # every valid row has EPE 0: no spread
    assert widths[400] < widths[40] / 2.5                  # ~ 1/sqrt(n): sqrt(10) = 3.2
    table = markdown_table({"m": summarize([good, bad] * 20)}, {"m": "M"}, {"m": "flow"}, "test")
    assert "0.500 [" in table and "bootstrap 95 %" in table
    empty = summarize([bad])                               # no valid row: no EPE, no interval
    assert math.isnan(empty["epe"]) and all(math.isnan(v) for v in empty["ci95"]["epe"])
