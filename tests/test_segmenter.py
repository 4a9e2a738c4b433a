"""The object segmenter (issue 36): checkpoints load or fail in one line, the targets mark
exactly the contact between two objects, and the shipped weights find an object at rest
throughout a rendered clip, which background subtraction cannot see."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from pipeline.segmenter import DEFAULT_WEIGHTS, UNet, Segmenter, SegmenterError, median_background, network_input, targets

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"


def test_targets_mark_foreground_and_contact_only_between_objects():
    seg = np.full((1, 8, 10), -1, np.int8)
    seg[0, 2:6, 1:4] = 0
    seg[0, 2:6, 4:7] = 1          # touches object 0 along column 3|4
    seg[0, 0, 9] = 2              # alone
    y = targets(seg, contact_px=1)
    assert y.shape == (1, 2, 8, 10) and y.dtype == np.float32
    np.testing.assert_array_equal(y[0, 0], seg[0] >= 0)
    contact = y[0, 1] > 0
    assert contact[2:6, 3:5].all()                       # both sides of the shared border
    assert not contact[:, :3].any() and not contact[:, 5:].any()   # nowhere else, not the lone object
    wide = targets(seg, contact_px=2)[0, 1] > 0                    # a band of 2 px each side
    assert wide[2:6, 2:6].all() and not wide[:, :2].any() and not wide[:, 6:].any()


def test_network_input_shape_and_motion_channel():
    frames = np.zeros((3, 16, 24, 3), np.uint8)
    frames[1, 4:8, 4:8] = 200
    bg = median_background(frames)
    x = network_input(frames, bg)
    assert x.shape == (3, 4, 16, 24) and x.dtype == np.float32
    assert x[1, 3, 5:7, 5:7].min() > 0.5 and x[0, 3].max() == 0.0


def test_any_image_size_gives_probabilities_of_that_size(tmp_path):
    path = tmp_path / "w.pt"
    torch.save({"channels": [4, 8, 8, 8], "state_dict": UNet((4, 8, 8, 8)).state_dict()}, path)
    net = Segmenter(path)
    frames = np.random.default_rng(0).integers(0, 255, (2, 37, 53, 3), dtype=np.uint8)
    fg, contact = net(frames, frames[0])
    assert fg.shape == contact.shape == (2, 37, 53) and 0 <= fg.min() and fg.max() <= 1


def test_bad_checkpoints_are_one_error(tmp_path):
    with pytest.raises(SegmenterError, match="no segmenter checkpoint"):
        Segmenter(tmp_path / "missing.pt")
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(SegmenterError, match="bad.pt: not a segmenter checkpoint"):
        Segmenter(bad)


def _box_at_rest_and_rolling_ball():
    """Rendered frames (192 x 144) of a box that never moves (label 0) and a ball rolling past it
    (label 1)."""
    from pipeline.render import render_scene
    from pipeline.scene import Scene

    scene = Scene.from_dict({"duration": 1.0, "fps": 30, "camera": {"height": 1.2, "pitch": 40.0, "fov": 45.0},
                             "objects": [
                                 {"shape": "box", "size": {"width": 0.2, "depth": 0.2, "height": 0.2}, "mass": 2.0,
                                  "position": [0.25, -0.6, 0.1]},
                                 {"shape": "sphere", "size": {"radius": 0.08}, "mass": 0.5,
                                  "position": [-0.5, -0.8, 0.08], "linear_velocity": [0.8, 0.0, 0.0]}]})
    return render_scene(scene, 192, 144)[1]


@pytest.mark.skipif(not DEFAULT_WEIGHTS.exists(), reason="no shipped segmenter weights")
def test_shipped_weights_find_an_object_at_rest_throughout():
    """A ball rolls past a box that never moves: the median background holds the box, so
    background subtraction sees nothing there; the segmenter finds the whole box in every frame."""
    from pipeline.metrics import observation_scores
    from pipeline.observe import segment_objects
    from pipeline.image_tracks import still_tracks
    from pipeline.masks import label_objects, pseudo_masks

    fr = _box_at_rest_and_rolling_ball()
    median = label_objects(pseudo_masks(fr.rgb), max_objects=4)
    seg = segment_objects(fr.rgb, fr.rgb, "segmenter", 4)
    still = [True, False]
    s_median = observation_scores(fr.seg, median, still)
    s_net = observation_scores(fr.seg, seg, still)
    assert s_median["still_iou"] < 0.2                      # background subtraction: the box is background
    assert s_net["still_iou"] >= 0.7 and s_net["moving_iou"] >= 0.6, (s_net["per_object"])
    assert len(still_tracks(seg, 4)) == 2
    # the box at rest is part of the proposed scene (perception keeps segmenter tracks that do not move)
    from pipeline.perception import propose
    props = propose(seg, None, 30, 1.0, 4, still=True)
    assert {len(sc.objects) for sc in props.scenes} == {2}


@pytest.mark.skipif(not DEFAULT_WEIGHTS.exists(), reason="no shipped segmenter weights")
def test_hybrid_finds_the_mover_first_and_the_object_at_rest():
    """``mask_method: hybrid``: a ball rolls past a box that never moves. Both are found whole;
    the mover (confirmed by background subtraction) gets id 0, the object at rest id 1."""
    from pipeline.metrics import observation_scores
    from pipeline.observe import hybrid_objects

    fr = _box_at_rest_and_rolling_ball()
    seg = hybrid_objects(fr.rgb, fr.rgb, 4)
    s = observation_scores(fr.seg, seg, [True, False])
    assert s["n_pred"] == 2 and s["still_iou"] >= 0.7 and s["moving_iou"] >= 0.6, s["per_object"]
    match = {o["true"]: o["pred"] for o in s["per_object"]}
    assert match == {1: 0, 0: 1}                            # the ball (true 1) is object 0


@pytest.mark.skipif(not DEFAULT_WEIGHTS.exists(), reason="no shipped segmenter weights")
def test_hybrid_candidates_record_each_track_and_its_decision_without_changing_the_result():
    """``hybrid_objects(..., candidates=[])`` records every segmenter candidate with the decision the
    rules took (``benchmarks/observation_candidates.py`` scores them): the rolling ball is a mover,
    the box an object at rest with an unchanging silhouette; the objects returned are the same."""
    from pipeline.observe import hybrid_objects

    fr = _box_at_rest_and_rolling_ball()
    cands: list = []
    seg = hybrid_objects(fr.rgb, fr.rgb, 4, candidates=cands)
    assert np.array_equal(seg, hybrid_objects(fr.rgb, fr.rgb, 4))
    by_truth = {}
    for c in cands:
        assert c["mask"].shape == fr.seg.shape and c["mask"].dtype == bool
        ious = [((c["mask"] & (fr.seg == k)).sum() / max(1, (c["mask"] | (fr.seg == k)).sum()), k) for k in (0, 1)]
        iou, k = max(ious)
        if iou >= 0.5:
            by_truth[k] = c
    assert by_truth[1]["decision"] == "mover" and by_truth[1]["travel"] >= 1.0, by_truth[1]
    assert by_truth[0]["decision"] == "at_rest" and by_truth[0]["stability"] >= 0.95 and by_truth[0]["seen"] == 1.0
    assert by_truth[0]["kept"] and by_truth[1]["kept"]
    box, ball = (fr.seg[0] == 0).sum(), (fr.seg[0] == 1).sum()     # the size class compares areas
    assert by_truth[0]["size_ratio"] == pytest.approx(box / ball, rel=0.3), (by_truth[0], box, ball)
    assert all(not c["kept"] for c in cands if c["decision"] == "rejected")


def _box_beside_small_ball(width: float):
    """Rendered frames (192 x 144) of a box of side ``width`` m at rest (label 0) and a 4 cm ball
    rolling past it (label 1)."""
    from pipeline.render import render_scene
    from pipeline.scene import Scene

    scene = Scene.from_dict({"duration": 1.0, "fps": 30, "camera": {"height": 1.2, "pitch": 40.0, "fov": 45.0},
                             "objects": [
                                 {"shape": "box", "size": {"width": width, "depth": width, "height": width},
                                  "mass": 2.0, "position": [0.35, -0.5, width / 2]},
                                 {"shape": "sphere", "size": {"radius": 0.04}, "mass": 0.5,
                                  "position": [-0.5, -0.8, 0.04], "linear_velocity": [0.8, 0.0, 0.0]}]})
    return render_scene(scene, 192, 144)[1]


@pytest.mark.skipif(not DEFAULT_WEIGHTS.exists(), reason="no shipped segmenter weights")
def test_hybrid_keeps_an_object_at_rest_of_the_scene_size_class_and_drops_scenery_sized_ones():
    """The size class of objects at rest (``REST_SIZE_CLASS``): a 30 cm box beside a 4 cm ball
    (about 24 times its area: objects of one rendered scene reach 30) is kept as an object at rest;
    a 45 cm one (about 57 times: the size of the scenery at rest beside a tossed ball on real clips)
    is not; the ball is the mover in both."""
    from pipeline.observe import REST_SIZE_CLASS, hybrid_objects

    for width, kept in ((0.3, True), (0.45, False)):
        fr = _box_beside_small_ball(width)
        ratio = (fr.seg[0] == 0).sum() / (fr.seg[0] == 1).sum()
        assert (16 < ratio < REST_SIZE_CLASS) if kept else ratio > 1.5 * REST_SIZE_CLASS, ratio
        cands: list = []
        seg = hybrid_objects(fr.rgb, fr.rgb, 4, candidates=cands)
        box = [c for c in cands if c["decision"] == "at_rest"]
        assert len(box) == 1 and box[0]["kept"] == kept and box[0]["size_ratio"] == pytest.approx(ratio, rel=0.2)
        assert int(seg.max()) + 1 == (2 if kept else 1)
        ball = (seg == 0) & (fr.seg == 1)
        assert ball.sum() >= 0.5 * (fr.seg == 1).sum()               # id 0 is the ball, the mover


def test_mask_stability_is_the_median_overlap_of_consecutive_silhouettes():
    """A square of side s shifted by d px per frame overlaps its last silhouette at IoU
    (s - d) / (s + d); one that does not move at 1; one seen once at 0."""
    from pipeline.observe import mask_stability

    T, s, d = 6, 10, 5
    m = np.zeros((T, 40, 60), bool)
    for t in range(T):
        m[t, 10:10 + s, 2 + d * t: 2 + d * t + s] = True
    assert mask_stability(m, np.arange(T)) == pytest.approx((s - d) / (s + d))
    still = np.repeat(m[:1], T, axis=0)
    assert mask_stability(still, np.arange(T)) == 1.0
    assert mask_stability(m, np.array([3])) == 0.0


@pytest.mark.skipif(not DEFAULT_WEIGHTS.exists(), reason="no shipped segmenter weights")
def test_anchored_keeps_the_movers_of_motion_makes_them_whole_and_adds_the_object_at_rest():
    """``mask_method: anchored``: the movers are background subtraction's (here: the ball's
    true masks cut to a crescent, the part a slow object shows), the segmenter completes them
    and adds the box at rest after them; scenery-free frames give no extra object."""
    from pipeline.metrics import observation_scores
    from pipeline.observe import anchored_objects

    fr = _box_at_rest_and_rolling_ball()
    ball = fr.seg == 1
    crescent = ball.copy()
    for t in range(len(ball)):                  # keep the right (leading) 45 % of the ball's columns
        cols = np.flatnonzero(ball[t].any(axis=0))
        if cols.size:
            crescent[t, :, : cols[0] + int(0.55 * cols.size)] = False
    movers = np.where(crescent, 0, -1).astype(np.int8)
    explain = []
    seg = anchored_objects(fr.rgb, fr.rgb, movers, 4, explain=explain)
    s = observation_scores(fr.seg, seg, [True, False])
    before = observation_scores(fr.seg, movers, [True, False])
    assert s["n_pred"] == 2 and [e["kind"] for e in explain] == ["mover", "at_rest"], explain
    match = {o["true"]: o["pred"] for o in s["per_object"]}
    assert match == {1: 0, 0: 1}                            # the mover keeps id 0
    assert s["moving_iou"] >= before["moving_iou"] + 0.2 and s["moving_iou"] >= 0.7, (before, s)
    assert s["still_iou"] >= 0.7
    # one object allowed: the mover only (motion is the stronger evidence)
    assert int(anchored_objects(fr.rgb, fr.rgb, movers, 1).max()) == 0


@pytest.mark.skipif(not DEFAULT_WEIGHTS.exists(), reason="no shipped segmenter weights")
def test_observe_with_anchored_keeps_the_median_movers(tmp_path):
    """``dynamics infer --mask-method anchored`` observes as ``median`` decides what moves: on a
    clip of one moving disc both find one object, over the same frames."""
    from conftest import moving_disc_avi
    from pipeline.observe import observe

    clip = moving_disc_avi(tmp_path / "disc.avi", n=60)
    med = observe(clip, None, None, 30, 1.0, mask_method="median")
    anc = observe(clip, None, None, 30, 1.0, mask_method="anchored")
    assert anc.mask_method == "anchored" and anc.seg.shape == med.seg.shape
    assert int(med.seg.max()) == int(anc.seg.max()) == 0
    assert np.array_equal((anc.seg == 0).any(axis=(1, 2)), (med.seg == 0).any(axis=(1, 2)))
    assert ((anc.seg == 0) & (med.seg == 0)).sum() >= 0.9 * (med.seg == 0).sum()   # completes, never drops


def test_at_rest_needs_a_steady_confident_silhouette_seen_throughout():
    """An object at rest (hybrid): seen in nearly every frame, the same silhouette, a sure
    segmenter; scenery that flickers, is seen briefly or is marked unsure is not one."""
    from pipeline.observe import _at_rest
    T = 20
    box = np.zeros((T, 30, 40), bool)
    box[:, 10:20, 10:22] = True
    fg = np.where(box, 0.97, 0.02).astype(np.float32)
    frames = np.arange(T)
    assert _at_rest(box, fg, frames, T)
    assert not _at_rest(box, np.where(box, 0.7, 0.0).astype(np.float32), frames, T)     # unsure
    assert not _at_rest(box[:8], fg[:8], frames[:8], T)                                 # seen briefly
    flicker = box.copy()
    flicker[::2, 10:20, 16:22] = False                                                  # half the mask comes and goes
    assert not _at_rest(flicker, fg, frames, T)
    occluded = box.copy()
    occluded[5:7, 10:20, 10:16] = False                                                 # a mover passes in front twice
    assert _at_rest(occluded, fg, frames, T)


def test_slow_object_must_end_where_it_did_not_start():
    """A slow object (hybrid): a disc pushed 0.75 diameters over the window, whose pixels barely
    flow, is one; a bar at rest whose left part a mover covers for 8 of 24 frames travels as far
    in its outline, comes back, and is not (``SLOW_NET``, ``net_shift``)."""
    from pipeline.image_tracks import find_tracks
    from pipeline.observe import _slow_object
    T, H, W = 24, 60, 80
    yy, xx = np.mgrid[:H, :W]
    disc = np.stack([(xx - (30 + 9.0 * t / (T - 1))) ** 2 + (yy - 30) ** 2 <= 36 for t in range(T)])
    bar = np.zeros((T, H, W), bool)
    bar[:, 26:34, 20:60] = True
    bar[8:16, 26:34, 20:40] = False                                    # occluded from the left
    for m in (disc, bar):
        tr = find_tracks(np.where(m, 0, -1).astype(np.int8))[0]
        assert tr.travel >= 0.25 * tr.diameter                        # both shift by "travel"
    fg = lambda m: np.where(m, 0.97, 0.02).astype(np.float32)          # noqa: E731
    t_disc = find_tracks(np.where(disc, 0, -1).astype(np.int8))[0]
    t_bar = find_tracks(np.where(bar, 0, -1).astype(np.int8))[0]
    assert _slow_object(t_disc, disc, fg(disc), T)
    assert not _slow_object(t_bar, bar, fg(bar), T)


def test_interpolate_is_the_weighted_mean_of_two_checkpoints(tmp_path):
    """WiSE-FT weights (pipeline.segmenter.interpolate): alpha 0 and 1 give the two checkpoints,
    0.5 their mean; two different networks are one error."""
    import torch
    from pipeline.segmenter import _save, interpolate
    torch.manual_seed(0)
    a, b = UNet(), UNet()
    with torch.no_grad():
        for p in b.parameters():
            p.add_(1.0)
    _save(a, tmp_path / "a.pt")
    _save(b, tmp_path / "b.pt")
    interpolate(tmp_path / "a.pt", tmp_path / "b.pt", tmp_path / "m.pt", alpha=0.5)
    m = Segmenter(tmp_path / "m.pt").net.state_dict()
    sa, sb = a.state_dict(), b.state_dict()
    for k in sa:
        if sa[k].is_floating_point():
            torch.testing.assert_close(m[k], 0.5 * (sa[k] + sb[k]))
    interpolate(tmp_path / "a.pt", tmp_path / "b.pt", tmp_path / "one.pt", alpha=1.0)
    one = Segmenter(tmp_path / "one.pt").net.state_dict()
    for k in sb:
        torch.testing.assert_close(one[k], sb[k])
    torch.save({"channels": [8, 16, 24, 32], "state_dict": UNet((8, 16, 24, 32)).state_dict()}, tmp_path / "small.pt")
    with pytest.raises(SegmenterError, match="not the same network"):
        interpolate(tmp_path / "a.pt", tmp_path / "small.pt", tmp_path / "x.pt")


def test_still_weight_scales_the_cross_entropy_of_static_object_pixels_only():
    """loss_fn(still_weight=w): a missed object pixel the background holds (difference channel
    below STATIC_DIFF) pulls w times as hard in the cross-entropy as with w = 1; a missed moving
    object pixel and a background pixel are unchanged; w < 1 or w without the input is one error."""
    from pipeline.segmenter import STATIC_DIFF, loss_fn
    H, W = 4, 4
    y = torch.zeros(1, 2, H, W)
    y[0, 0, 0, 0] = 1.0                       # static object pixel
    y[0, 0, 0, 1] = 1.0                       # moving object pixel
    x = torch.zeros(1, 4, H, W)
    x[0, 3, 0, 1] = 0.5                       # it differs from the background
    x[0, 3, 0, 0] = 0.5 * STATIC_DIFF
    x[0, 3, 1, 1] = 0.5                       # a background pixel that differs (a shadow)

    def grad(w: float) -> torch.Tensor:
        logits = torch.full((1, 2, H, W), -2.0, requires_grad=True)   # everything called background
        loss_fn(logits, y, x, still_weight=w).backward()
        return logits.grad[0, 0]

    g1, g5 = grad(1.0), grad(5.0)
    # the BCE term's gradient on a target-1 pixel at logit -2 is (sigmoid(-2) - 1) / (H * W)
    bce = (torch.sigmoid(torch.tensor(-2.0)) - 1.0) / (H * W)
    torch.testing.assert_close(g5[0, 0] - g1[0, 0], 4.0 * bce)
    torch.testing.assert_close(g5[0, 1], g1[0, 1])
    torch.testing.assert_close(g5[1, 1], g1[1, 1])
    assert g5[0, 0] < g5[0, 1] < 0           # the static miss now costs most
    with pytest.raises(SegmenterError, match="still_weight"):
        loss_fn(torch.zeros(1, 2, H, W), y, still_weight=5.0)
    with pytest.raises(SegmenterError, match="still_weight"):
        loss_fn(torch.zeros(1, 2, H, W), y, x, still_weight=0.5)


def _square_track(T: int = 10, step: float = 1.0, size: int = 6) -> np.ndarray:
    """``(T, 32, 48)`` bool masks of a square moving ``step`` px right per frame."""
    m = np.zeros((T, 32, 48), bool)
    for t in range(T):
        x = 4 + int(round(step * t))
        m[t, 10:10 + size, x:x + size] = True
    return m


def test_flow_moves_needs_the_pixels_to_flow_not_only_the_outline():
    """A mover's pixels flow with it; a mask that flickers over still pixels (scenery half
    recognised, a fragment) has a centroid that travels while the flow under it is zero."""
    from pipeline.observe import flow_moves

    m = _square_track(step=1.0)                 # 9 px in 10 frames: 1.5 diameters
    flow = np.zeros((9, 32, 48, 2), np.float32)
    flow[..., 0] = 1.0                           # the true motion, 1 px / frame to the right
    assert flow_moves(m, flow, diameter=6.0)
    assert not flow_moves(m, np.zeros_like(flow), diameter=6.0)       # outline only
    slow = flow * 0.2                                                  # 1.8 px in all: 0.3 diameters
    assert not flow_moves(m, slow, diameter=6.0)
    assert not flow_moves(np.zeros_like(m), flow, diameter=6.0)        # never seen



@pytest.mark.skipif(not DEFAULT_WEIGHTS.exists(), reason="no shipped segmenter weights")
def test_observe_keeps_a_uniform_box_that_leaves_the_view(tmp_path):
    """A PyBullet clip with true masks (truth set seed 0, clip 3): a green box of one colour slides
    out of the view in the first third of the window (a sliver stays at the border) while a capsule
    lies at rest. The motion test's flow (DIS at MOTION_FLOW_PRESET) carries the box's motion
    although its interior has no texture, so it is an object until it leaves; the capsule stays an
    object at rest."""
    from pipeline.metrics import observation_scores
    from pipeline.observe import observe, truth_in_window
    from pipeline.truthsets import pybullet_scenes
    from pipeline.truthsets.common import generate_clip, write_clip
    clip = generate_clip(pybullet_scenes, seed=0, index=3)
    folder = write_clip(tmp_path / "clip", clip)
    obs = observe(folder / "video.mp4", clip.fps, None, 30, 1.0, mask_method="hybrid")
    truth, frames = truth_in_window(clip.seg, obs)
    area = np.stack([(truth == k).sum(axis=(1, 2)) for k in range(2)])      # (2, T) px
    leaving = int(np.argmin(area[:, -1] / area[:, 0]))
    assert area[leaving, -1] < 0.1 * area[leaving, 0]                        # a sliver at the border
    assert area[1 - leaving].min() > 0.9 * area[1 - leaving].max()           # the other stays whole
    still = np.linalg.norm(clip.pos[frames] - clip.pos[frames][:1], axis=-1).max(axis=0) < 0.005
    assert not still[leaving] and still[1 - leaving]
    s = observation_scores(truth, obs.seg, list(still))
    match = {o["true"]: o for o in s["per_object"]}
    assert s["n_pred"] == 2 and match[1 - leaving]["iou"] >= 0.8, match
    pred = obs.seg == match[leaving]["pred"]
    whole = np.nonzero(area[leaving] >= 0.25 * area[leaving, 0])[0]          # before it is a sliver
    box = truth == leaving
    iou = [(pred[t] & box[t]).sum() / (pred[t] | box[t]).sum() for t in whole]
    assert len(whole) >= 5 and np.mean(iou) >= 0.7, iou


def test_merge_fragments_joins_pieces_of_one_colour_only():
    """Two tracks that touch in every frame are one object when they have one colour (the lit and
    the shaded half of a red ball: same chromaticity, half the brightness); a red ball touching a
    blue box and a red ball touching its grey cast shadow stay apart."""
    from pipeline.observe import merge_fragments

    T, H, W = 6, 32, 64
    yy, xx = np.mgrid[:H, :W]
    frames = np.full((T, H, W, 3), 128, np.uint8)                       # grey floor
    left, right, box, shadow = (np.zeros((T, H, W), bool) for _ in range(4))
    for t in range(T):
        disc = (xx - (16 + t)) ** 2 + (yy - 12) ** 2 <= 36
        left[t], right[t] = disc & (xx < 16 + t), disc & (xx >= 16 + t)
        box[t, 6:18, 23 + t:33 + t] = True
        shadow[t] = ((xx - (16 + t)) ** 2 + (yy - 19) ** 2 <= 16) & ~disc
    frames[left] = (200, 40, 40)
    frames[right] = (100, 20, 20)                                         # the same red in shade
    frames[box] = (40, 40, 200)
    frames[shadow] = (70, 70, 70)                                         # the floor, darker
    ranked = [(None, left, []), (None, right, [1]), (None, box, []), (None, shadow, [])]
    kinds = ["mover", "mover", "mover", "mover_bs_only"]
    out, out_kinds = merge_fragments(ranked, kinds, frames)
    assert len(out) == 3 and out_kinds == ["mover", "mover", "mover_bs_only"]
    np.testing.assert_array_equal(out[0][1], left | right)               # the ball, whole
    assert out[0][2] == [1]
    np.testing.assert_array_equal(out[1][1], box)
    np.testing.assert_array_equal(out[2][1], shadow)


def test_merge_fragments_joins_pieces_with_a_gap_that_move_as_one_rigid_body():
    """dev/12: an upright can sliding across a table comes back as its top and the rest of it, a gap
    between them, one colour, their offset fixed while they travel: one object, whose silhouette is
    the convex hull of both (the whole can). Two balls of that colour that do not keep their offset
    (one overtakes the other), and two pieces of one colour that do not move, stay apart."""
    from pipeline.observe import merge_fragments, rigid_pair

    T, H, W = 12, 48, 96
    yy, xx = np.mgrid[:H, :W]
    frames = np.full((T, H, W, 3), 128, np.uint8)
    top, body, other, still_a, still_b = (np.zeros((T, H, W), bool) for _ in range(5))
    for t in range(T):
        x = 10 + 3 * t                                                   # 3 px / frame
        top[t, 6:12, x:x + 10] = True                                    # the can's top...
        body[t, 15:30, x:x + 10] = True                                  # ...3 px of gap, the rest
        other[t] = (xx - (10 + 5 * t)) ** 2 + (yy - 40) ** 2 <= 16       # a faster ball below
        still_a[t, 36:42, 80:86] = True
        still_b[t, 44:47, 80:86] = True
    for m in (top, body, other, still_a, still_b):
        frames[m] = (180, 170, 160)                                      # one colour
    assert rigid_pair(top, body)
    assert not rigid_pair(top, other)                                    # the offset changes 2 px a frame
    assert not rigid_pair(still_a, still_b)                              # a fixed offset, but no travel
    ranked = [(None, top, []), (None, body, [2]), (None, other, []), (None, still_a, []), (None, still_b, [])]
    out, kinds = merge_fragments(ranked, ["mover", "mover", "mover", "mover", "mover"], frames)
    assert len(out) == 4 and kinds == ["mover"] * 4
    can = np.zeros((T, H, W), bool)
    for t in range(T):
        can[t, 6:30, 10 + 3 * t:20 + 3 * t] = True                       # top, gap and body: the hull
    np.testing.assert_array_equal(out[0][1], can)
    assert out[0][2] == [2]
    np.testing.assert_array_equal(out[1][1], other)


def test_join_movers_joins_a_mover_lost_and_found_again_only():
    """A fast square the tracker loses half way comes back as a second track further along its
    path: one mover. Two halves of a square seen together (two objects that touch and move alike)
    stay two; the same second piece reappearing far away after a gap is another object."""
    from pipeline.image_tracks import find_tracks
    from pipeline.observe import join_movers

    T, H, W = 10, 32, 64
    seg = np.full((T, H, W), -1, np.int8)
    for t in range(T):
        x = 2 + 3 * t                                   # 3 px / frame to the right
        seg[t, 4:10, x:x + 6] = 0 if t < 5 else 1       # lost at t = 5: a new track
        seg[t, 20:26, 50 - 2 * t:53 - 2 * t] = 2        # left half of another square
        seg[t, 20:26, 53 - 2 * t:56 - 2 * t] = 3        # its right half, moving with it
    tracks = find_tracks(seg, None, min_frames=1)
    movers = [(tr, seg == tr.label, [5] if tr.label == 1 else []) for tr in tracks]
    joined = join_movers(movers)
    assert len(joined) == 3
    np.testing.assert_array_equal(joined[0][1], (seg == 0) | (seg == 1))
    assert joined[0][2] == [5]                          # background-subtraction stand-ins merged
    np.testing.assert_array_equal(joined[1][1], seg == 2)
    np.testing.assert_array_equal(joined[2][1], seg == 3)
    # the second piece far from where the first ended is not the same object
    far = seg.copy()
    far[5:][far[5:] == 1] = -1
    far[8, 26:32, 56:62] = 1                            # reappears 47 px away after a 4-frame gap (reach 36 px)
    tracks = find_tracks(far, None, min_frames=1)
    movers = [(tr, far == tr.label, []) for tr in tracks if tr.label in (0, 1)]
    assert len(join_movers(movers)) == 2


def test_attached_parts_drop_a_cast_shadow_and_keep_objects_that_touch():
    """A ball's cast shadow is segmented as a second mover: smaller, touching the ball in every
    frame, flowing with it. It is a part, not an object. Two balls that touch only while they
    collide stay two, and so does a small ball rolling along a larger region it lends its flow
    to (it moves more than that region)."""
    from pipeline.observe import attached_parts

    T, H, W = 10, 40, 80
    flow = np.zeros((T - 1, H, W, 2), np.float32)

    def moving(rows, cols0, step, speed):
        m = np.zeros((T, H, W), bool)
        for t in range(T):
            x = cols0[0] + int(round(step * t))
            m[t, rows[0]:rows[1], x:x + cols0[1]] = True
            if t < T - 1:
                flow[t][m[t]] = (speed, 0.0)
        return m

    ball = moving((6, 14), (2, 8), 2.0, 2.0)            # 8 x 8 px, 2 px / frame
    shadow = moving((15, 18), (2, 8), 2.0, 2.0)         # 3 x 8 px just under it (1 px gap)
    assert attached_parts([ball, shadow], flow) == {1}
    assert attached_parts([shadow, ball], flow) == {0}

    flow[:] = 0
    left = moving((24, 32), (2, 8), 3.0, 3.0)           # 3 px / frame to the right
    right = np.zeros((T, H, W), bool)                    # at 36..41 until hit at t = 8, then away
    for t in range(T):
        x = 36 if t < 8 else 36 + 3 * (t - 7)
        right[t, 24:32, x:x + 6] = True
        if t < T - 1:
            flow[t][right[t]] = (3.0 if t >= 7 else 0.0, 0.0)
    assert attached_parts([left, right], flow) == set()

    flow[:] = 0
    region = np.zeros((T, H, W), bool)
    region[:, 20:34, 10:70] = True                       # a large region with a little flow
    flow[:, 20:34, 10:70] = (0.3, 0.0)
    small = moving((14, 20), (10, 6), 4.0, 4.0)          # a small ball rolling along its top edge
    assert attached_parts([region, small], flow) == set()


def test_rigid_size_keeps_objects_entering_or_hidden_and_drops_flicker():
    """A disc crossing the frame, one entering it from the edge and one hidden behind a post for
    a few frames keep the size of one rigid body; a speck that flashes to a large blob in a few
    frames (flicker over a backdrop, a caption) does not."""
    from pipeline.observe import rigid_size

    T, H, W, r = 30, 60, 120, 8
    yy, xx = np.mgrid[0:H, 0:W]

    def disc(cx):
        return (xx - cx) ** 2 + (yy - 30) ** 2 <= r * r

    crossing = np.stack([disc(20 + 2 * t) for t in range(T)])
    entering = np.stack([disc(-r - 1 + t) for t in range(T)])      # from outside the left edge
    hidden = crossing.copy()
    hidden[:, :, 50:62] = False                                      # a post in front
    assert crossing.sum(axis=(1, 2)).min() > 0 and entering[0].sum() == 0
    assert rigid_size(crossing) and rigid_size(entering) and rigid_size(hidden)
    assert rigid_size(np.zeros((T, H, W), bool))

    flicker = np.zeros((T, H, W), bool)
    flicker[:, 30, 60] = True                                        # a 1 px speck ...
    flicker[[5, 17, 23]] |= disc(60)                                 # ... and a large blob in 3 frames
    assert not rigid_size(flicker)


def test_fit_seg_keeps_the_movers_renumbered_and_all_when_none_moves():
    """``Observation.fit_seg``: what the search fits is the observed objects that move, numbered
    0..m-1 in their order; with no mover (or no flags) it is the whole observation."""
    from pipeline.observe import Observation

    seg = np.full((2, 4, 6), -1, np.int8)
    seg[:, 0, 0], seg[:, 1, 1], seg[:, 2, 2] = 0, 1, 2
    obs = Observation(frames=None, seg=seg, flow=None, clip=None, start=0.0, auto=True, crop=(0, 0, 6, 4),
                      size=(6, 4), scene_fps=30, flow_method="dis", mask_method="hybrid", moving=(False, True, True))
    fit = obs.fit_seg
    assert fit[0, 0, 0] == -1 and fit[0, 1, 1] == 0 and fit[0, 2, 2] == 1
    assert (fit >= 0).sum() == 4 and fit.dtype == np.int8
    for moving in (None, (False, False, False), (True, True, True)):
        obs.moving = moving
        assert np.array_equal(obs.fit_seg, seg)


@pytest.mark.skipif(not DEFAULT_WEIGHTS.exists(), reason="no shipped segmenter weights")
def test_observe_with_hybrid_flags_the_object_at_rest_and_fits_the_mover(tmp_path):
    """``observe(..., mask_method="hybrid")`` on a video of a ball rolling past a box at rest:
    both are observed (``seg``), the ball flagged moving and the box not, and the search's target
    (``fit_seg``) is the ball alone, whose masks it keeps."""
    import cv2
    from pipeline.metrics import observation_scores
    from pipeline.observe import observe, truth_in_window

    fr = _box_at_rest_and_rolling_ball()
    path = tmp_path / "box_and_ball.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, fr.rgb.shape[2:0:-1])
    for f in fr.rgb:
        writer.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    writer.release()
    obs = observe(path, None, 0.0, 30, 1.0, mask_method="hybrid")
    assert obs.moving is not None and sorted(obs.moving) == [False, True], obs.moving
    truth, _ = truth_in_window(fr.seg, obs)
    s = observation_scores(truth, obs.seg, [True, False])
    assert s["n_pred"] == 2 and s["still_iou"] >= 0.7 and s["moving_iou"] >= 0.6, s["per_object"]
    ball = observation_scores(np.where(truth == 1, 0, -1).astype(np.int8), obs.fit_seg, [False])
    assert int(obs.fit_seg.max()) == 0 and ball["moving_iou"] >= 0.6, ball["per_object"]


@pytest.fixture(scope="module")
def two_clips(tmp_path_factory):
    """Two rendered truth-set clips (MuJoCo, split seed 40) and the temporary folder a killed writer leaves."""
    from pipeline.truthsets.__main__ import generate_set
    out = tmp_path_factory.mktemp("clips")
    generate_set("mujoco", 2, 40, out, width=160, height=120, duration=0.5, progress=False)
    stale = out / ".clip-00002.abcd.tmp"
    stale.mkdir()
    (stale / "truth.npz").write_bytes((out / "clip-00000" / "truth.npz").read_bytes())
    return out


def test_load_set_takes_the_same_frames_in_any_number_of_processes(two_clips):
    """The frames drawn per clip depend on the seed only; a killed writer's folder is no clip."""
    from pipeline.segmenter import _load_set, clip_folders
    folders = clip_folders([two_clips])
    assert [f.name for f in folders] == ["clip-00000", "clip-00001"]
    x0, y0 = _load_set(folders, (160, 120), 5, np.random.default_rng(3), workers=0)
    x2, y2 = _load_set(folders, (160, 120), 5, np.random.default_rng(3), workers=2)
    assert x0.shape == (10, 4, 120, 160) and x0.dtype == np.float16 and y0.shape == (10, 2, 120, 160)
    np.testing.assert_array_equal(x0, x2)
    np.testing.assert_array_equal(y0, y2)
    assert y0[:, 0].any()                                   # the objects are in the targets


def test_training_with_batch_workers_lowers_the_loss_and_keeps_its_channels(two_clips, tmp_path):
    """A network of other channels trains with batch-making processes and a time schedule, its loss
    falls, and the checkpoint loads back as that network."""
    from pipeline.segmenter import train
    card = train([two_clips], tmp_path / "s.pt", steps=40, batch=4, size=(160, 120), per_clip=6, seed=1,
                 channels=(8, 16, 24), workers=2, realism=True, realism_fraction=0.5, log_every=1000)
    assert card["steps"] == 40 and card["channels"] == [8, 16, 24] and card["workers"] == 2
    net = Segmenter(tmp_path / "s.pt").net
    assert net.channels == (8, 16, 24)
    assert card["first_loss"] > card["final_loss"]
    with pytest.raises(SegmenterError, match="time_schedule: needs max_minutes"):
        train([two_clips], tmp_path / "t.pt", steps=2, time_schedule=True)
    with pytest.raises(SegmenterError, match="realism_fraction"):
        train([two_clips], tmp_path / "t.pt", steps=2, realism=True, realism_fraction=1.5)
    assert not (tmp_path / "t.pt").exists()


def test_an_ensemble_gives_the_mean_of_its_members_probabilities(tmp_path):
    """pipeline.segmenter.ensemble: networks of different channels in one checkpoint, whose
    probabilities are the mean of each member's; an ensemble is no network to fine-tune."""
    from pipeline.segmenter import _save, ensemble
    torch.manual_seed(0)
    _save(UNet((8, 16)), tmp_path / "a.pt")
    _save(UNet((4, 8, 12)), tmp_path / "b.pt")
    ensemble([tmp_path / "a.pt", tmp_path / "b.pt"], tmp_path / "e.pt")
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 255, (3, 20, 28, 3), dtype=np.uint8)
    bg = median_background(frames)
    fa, ca = Segmenter(tmp_path / "a.pt")(frames, bg)
    fb, cb = Segmenter(tmp_path / "b.pt")(frames, bg)
    fe, ce = Segmenter(tmp_path / "e.pt")(frames, bg)
    assert fe.shape == (3, 20, 28)
    np.testing.assert_allclose(fe, (fa + fb) / 2, atol=1e-6)
    np.testing.assert_allclose(ce, (ca + cb) / 2, atol=1e-6)
    with pytest.raises(SegmenterError, match="an ensemble of 2 networks"):
        Segmenter(tmp_path / "e.pt").net
    with pytest.raises(SegmenterError, match="at least two"):
        ensemble([tmp_path / "a.pt"], tmp_path / "x.pt")
    with pytest.raises(SegmenterError, match="an ensemble of 2"):
        ensemble([tmp_path / "e.pt", tmp_path / "a.pt"], tmp_path / "x.pt")
    assert not (tmp_path / "x.pt").exists()


def test_realvideo_segmenter_weights_pick_the_observations_network(tmp_path, monkeypatch):
    """realvideo.segmenter_weights: null keeps the shipped network, wide the GPU-trained one (a
    wider network), a relative path is the params folder's; a missing file stops `dynamics infer`
    in one line naming the field, before any video is read; the chosen network is the one the
    main job passes to the observation (no process-wide default: the shipped one stays the
    default of every other caller)."""
    from pipeline import segmenter as S
    from pipeline.params import ParamsError, load_params
    from pipeline.reconstruct import reconstruct
    from pipeline.video import VideoError
    assert S.resolve_weights(None) is None and S.resolve_weights("shipped") is None
    assert S.resolve_weights("wide") == S.WIDE_WEIGHTS and S.WIDE_WEIGHTS.is_file()
    assert S.resolve_weights("w/a.pt", tmp_path) == tmp_path / "w" / "a.pt"
    wide, shipped = Segmenter(S.WIDE_WEIGHTS), Segmenter()
    assert sum(p.numel() for p in wide.net.parameters()) > 3 * sum(p.numel() for p in shipped.net.parameters())
    params = load_params(None)
    params["realvideo"]["segmenter_weights"] = str(tmp_path / "missing.pt")
    with pytest.raises(ParamsError, match=r"realvideo\.segmenter_weights: .*missing\.pt: no segmenter checkpoint"):
        reconstruct(tmp_path / "no_video.mp4", tmp_path / "out", params)
    assert not (tmp_path / "out").exists()
    params["realvideo"]["segmenter_weights"] = "wide"
    with pytest.raises(VideoError, match="no_video.mp4"):   # past the weights: the video is what is missing
        reconstruct(tmp_path / "no_video.mp4", tmp_path / "out", params)
    passed = []

    def observe_stub(*args, **kwargs):   # stands in for the observation: records its segmenter
        passed.append(kwargs.get("segmenter", args[8] if len(args) > 8 else None))
        raise VideoError("observation reached")
    monkeypatch.setattr("pipeline.reconstruct.observe", observe_stub)
    for choice, path in (("wide", S.WIDE_WEIGHTS), (None, DEFAULT_WEIGHTS)):
        params["realvideo"]["segmenter_weights"] = choice
        with pytest.raises(VideoError, match="observation reached"):
            reconstruct(tmp_path / "no_video.mp4", tmp_path / "out", params, start=0.0)
        assert Path(passed[-1].path) == path
    assert Path(S.shipped().path) == DEFAULT_WEIGHTS       # the default of every other caller


def test_a_crescent_of_a_slow_object_does_not_set_the_movers_size_class():
    """movers_and_stills_of_one_scene: a background-subtraction crescent lying on a slow object at
    rest is dropped before the movers' size is taken, so a tall box at rest 100 times the
    crescent's area but 4 times the slow object's stays; beside a true small mover of its own
    (a ball elsewhere) the same box, 64 times the ball, is scenery-sized and goes."""
    from pipeline.observe import REST_SIZE_CLASS, movers_and_stills_of_one_scene

    T, H, W = 6, 120, 160
    slow = np.zeros((T, H, W), bool)
    slow[:, 50:60, 10:30] = True                      # 200 px, at rest or nearly
    crescent = np.zeros((T, H, W), bool)
    crescent[:, 50:60, 27:31] = True                  # 40 px, 3/4 of it on the slow object
    box = np.zeros((T, H, W), bool)
    box[:, 20:60, 80:100] = True                      # 800 px
    ball = np.zeros((T, H, W), bool)
    for t in range(T):
        ball[t, 100:104, 10 + 10 * t:14 + 10 * t] = True   # 16 px, moving
    areas = [200.0, 800.0]
    assert 800 / 40 < REST_SIZE_CLASS < 800 / 16     # only the order decides the crescent case

    keep_unseen, keep_still, ref = movers_and_stills_of_one_scene([], [crescent], [slow, box], areas)
    assert keep_unseen == [False] and keep_still == [True, True] and ref is None
    crescent[:] = False
    crescent[:, 70:80, 27:31] = True                  # the same track elsewhere: a mover of its own
    keep_unseen, keep_still, ref = movers_and_stills_of_one_scene([], [crescent], [slow, box], areas)
    assert keep_unseen == [True] and ref == pytest.approx(40.0) and keep_still == [True, True]
    keep_unseen, keep_still, ref = movers_and_stills_of_one_scene([ball], [], [slow, box], areas)
    assert ref == pytest.approx(16.0) and keep_still == [True, False]
    assert movers_and_stills_of_one_scene([], [], [box], [800.0]) == ([], [True], None)


def test_a_small_ball_thrown_across_a_large_object_at_rest_is_a_mover_not_its_crescent():
    """Real clip dev/07: a tennis ball a few px wide flies across a picture on the wall that the
    segmenter holds as an object at rest. Most of the ball's background-subtraction track lies on the
    picture, but it travels farther than the picture is large, which a crescent of a slow object
    (on its outline, moving less than its size) cannot: it stays a mover, sets the movers' size, and
    the picture, 180 times the ball, is scenery-sized and goes. The same track kept within the
    picture's size is still a crescent."""
    from pipeline.observe import REST_SIZE_CLASS, movers_and_stills_of_one_scene, outruns

    T, H, W = 8, 90, 160
    picture = np.zeros((T, H, W), bool)
    picture[:, 20:60, 40:80] = True                      # 1600 px: a disc of that area is 45 px wide
    ball = np.zeros((T, H, W), bool)
    for t in range(T):
        ball[t, 39:42, 35 + 8 * t:38 + 8 * t] = True     # 9 px, 56 px of travel, 5 of 8 frames on the picture
    assert (ball & picture).sum() > 0.5 * ball.sum()
    assert 1600 / 9 > REST_SIZE_CLASS
    assert outruns(ball, [picture], [1600.0])
    keep_unseen, keep_still, ref = movers_and_stills_of_one_scene([], [ball], [picture], [1600.0])
    assert keep_unseen == [True] and ref == pytest.approx(9.0) and keep_still == [False]

    near = np.zeros((T, H, W), bool)
    for t in range(T):
        near[t, 39:42, 50 + 4 * t:53 + 4 * t] = True     # 28 px of travel, all on the picture
    assert not outruns(near, [picture], [1600.0])
    keep_unseen, keep_still, ref = movers_and_stills_of_one_scene([], [near], [picture], [1600.0])
    assert keep_unseen == [False] and keep_still == [True] and ref is None
    assert not outruns(np.zeros((T, H, W), bool), [picture], [1600.0])


def test_left_behind_flags_the_place_a_resting_object_left_and_keeps_a_ball_crossing_its_path():
    """A box rests at A for 12 of 20 frames, then slides to B: the median background holds it at A,
    so differencing marks A from frame 12 on (a ghost) while the box is elsewhere. That track lies
    where the kept box was, in every frame it is seen: a ghost. A ball rolling down across the
    box's path lies there (half its pixels or more) in 5 of its 20 frames: an object of its own.
    Whatever lies on the box where the box is in that frame (a small ball in front of it) is not
    its ghost: only the places the box is not at that time count. With no kept objects nothing is
    a ghost."""
    from pipeline.observe import left_behind

    T, H, W = 20, 48, 96
    box = np.zeros((T, H, W), bool)
    for t in range(T):
        x = 10 if t < 12 else 10 + 8 * (t - 11)          # at rest, then 8 px / frame to the right
        box[t, 20:30, x:x + 10] = True
    ghost = np.zeros((T, H, W), bool)
    ghost[12:, 20:30, 10:20] = True                      # A, once the box has left it
    ball = np.zeros((T, H, W), bool)
    for t in range(T):
        y = 2 * t                                        # down through the box's row at t = 8..14
        ball[t, y:y + 6, 50:56] = True
    assert left_behind(ghost, [box])
    in_front = np.zeros((T, H, W), bool)
    for t in range(12, T):
        x = 10 + 8 * (t - 11)
        in_front[t, 22:28, x + 3:x + 7] = True            # on the sliding box, moving with it
    assert not left_behind(in_front, [box])
    assert not left_behind(ball, [box])
    assert not left_behind(ghost, [])
    assert not left_behind(np.zeros_like(ghost), [box])


def test_fine_probabilities_cut_the_working_crop_out_of_the_detection_pass():
    """The detection pass's probabilities (whole frame at 320 x 240 of a 640 x 480 video) over a
    working crop (x 160, y 120, 320 x 240 px original) at 80 x 60 px: the blob lands where the crop
    puts it; a detection pass that is not 1.5x finer than the working size gives None."""
    from pipeline.observe import FINE_SCALE, fine_probabilities
    p = np.zeros((2, 240, 320), np.float32)
    p[:, 100:120, 120:140] = 1.0                 # original px x 240..280, y 200..240
    out = fine_probabilities(p, (320, 240), (640, 480), (160, 120, 320, 240), (80, 60))
    assert out.shape == (2, 60, 80) and out.dtype == np.float32
    ys, xs = np.nonzero(out[0] > 0.5)           # 40..60 of the 160 x 120 det px of the crop, halved
    assert (ys.min(), ys.max(), xs.min(), xs.max()) == (20, 29, 20, 29)
    assert abs(out.sum() / 2 - 100.0) < 1e-3    # area averaging keeps the mass (400 px / 4)
    coarse = (round(160 / FINE_SCALE) + 2, round(120 / FINE_SCALE) + 2)   # finer, but not 1.5x
    assert fine_probabilities(p, (320, 240), (640, 480), (160, 120, 320, 240), coarse) is None


def test_fused_segmenter_keeps_the_larger_probability_of_either_scale():
    from pipeline.observe import _Fused, _Recorded
    rng = np.random.default_rng(0)
    own = (rng.random((3, 6, 8), dtype=np.float32), rng.random((3, 6, 8), dtype=np.float32))
    fine = (rng.random((3, 6, 8), dtype=np.float32), rng.random((3, 6, 8), dtype=np.float32))
    rec = _Recorded(lambda frames, bg: own)
    fused = _Fused(rec, fine)
    fg, contact = fused(np.zeros((3, 6, 8, 3), np.uint8), np.zeros((6, 8, 3), np.uint8))
    np.testing.assert_array_equal(fg, np.maximum(own[0], fine[0]))
    np.testing.assert_array_equal(contact, np.maximum(own[1], fine[1]))
    assert rec.probabilities is own
    other = _Fused(lambda frames, bg: (np.zeros((2, 6, 8), np.float32),) * 2, fine)   # another shape: alone
    assert other(np.zeros((2, 6, 8, 3), np.uint8), np.zeros((6, 8, 3), np.uint8))[0].max() == 0.0


@pytest.mark.skipif(not DEFAULT_WEIGHTS.exists(), reason="no shipped segmenter weights")
def test_observe_finds_a_small_ball_with_the_detection_pass_as_the_finer_scale(tmp_path):
    """A rendered clip with true masks (truth set MuJoCo seed 2, clip 2): a small ball at rest some
    20 px in area at the 160 x 120 working size, seen from the side far behind a larger moving
    object. With the working pass's probabilities alone the ball is not an object; fused with the
    detection pass's (320 x 240, ``fine_scale``) it is found, and the other object stays as it was."""
    from pipeline.metrics import observation_scores
    from pipeline.observe import observe, truth_in_window
    from pipeline.truthsets import mujoco_scenes
    from pipeline.truthsets.common import generate_clip, write_clip
    clip = generate_clip(mujoco_scenes, seed=2, index=2)
    folder = write_clip(tmp_path / "clip", clip)
    scores = {}
    for fine in (False, True):
        obs = observe(folder / "video.mp4", clip.fps, None, 30, 1.0, mask_method="hybrid", fine_scale=fine)
        truth, _ = truth_in_window(clip.seg, obs)
        areas = [(truth == k).sum() for k in range(2)]
        s = observation_scores(truth, obs.seg, [False, False])
        scores[fine] = {o["true"]: o["iou"] for o in s["per_object"]}
        ball, box = int(np.argmin(areas)), int(np.argmax(areas))
        assert areas[ball] < 60 * len(truth) < areas[box]
    assert scores[False].get(ball, 0.0) < 0.3 and scores[True][ball] >= 0.5, scores
    assert scores[True][box] >= scores[False][box] - 0.02 and scores[True][box] >= 0.8, scores


def test_fused_segmenter_does_not_take_a_cast_shadow_from_the_finer_scale():
    """Where the finer scale marks a pixel that is the background darkened with its colour kept (a
    cast shadow, :func:`pipeline.masks.shadow_like`), the working pass's probability stays; where
    it marks a pixel of another colour (an object), the maximum is taken."""
    from pipeline.masks import shadow_like
    from pipeline.observe import _Fused
    bg = np.full((6, 8, 3), (200, 150, 100), np.uint8)
    frames = np.repeat(bg[None], 2, axis=0).copy()
    frames[:, 1:3, 1:3] = (120, 90, 60)          # the background at 0.6 of its brightness: a shadow
    frames[:, 3:5, 5:7] = (40, 160, 40)          # green: an object
    assert shadow_like(frames, bg)[0, 1:3, 1:3].all() and not shadow_like(frames, bg)[0, 3:5, 5:7].any()
    own = np.full((2, 6, 8), 0.1, np.float32)
    fine = np.full((2, 6, 8), 0.9, np.float32)
    fg, _ = _Fused(lambda f, b: (own, own), (fine, fine))(frames, bg)
    assert np.allclose(fg[:, 1:3, 1:3], 0.1) and np.allclose(fg[:, 3:5, 5:7], 0.9)
    assert np.allclose(fg[:, 0, :], 0.9)          # the unchanged background is not a shadow either


def _disc_track(T: int, H: int, W: int, centres: list[tuple[float, float]], r: float) -> np.ndarray:
    yy, xx = np.mgrid[0:H, 0:W]
    return np.stack([(xx - cx) ** 2 + (yy - cy) ** 2 <= r * r for cx, cy in centres])


def test_cast_shadow_is_dropped_only_when_it_looks_like_one_and_moves_with_an_object():
    """dev/04: a red ball falls in front of a lit wall and its shadow falls with it, a few px away
    (not touching, so not a part). The shadow is the wall darkened, with the wall's chromaticity and
    its texture still there, and moves as the ball does: dropped. Kept: a grey object that moves
    with the ball but hides the wall's texture (a grey object over a grey floor), a shadow-coloured
    object moving on its own path, and one whose companion is as grey as itself."""
    from pipeline.observe import cast_shadows, texture_kept, velocity_coupling

    T, H, W = 12, 80, 80
    rng = np.random.default_rng(0)
    texture = rng.normal(0.0, 12.0, (H, W, 1)) + np.linspace(-10.0, 10.0, W)[None, :, None]
    wall = np.clip(np.array([200.0, 190.0, 180.0]) + texture, 0, 255)            # (H, W, 3)
    background = wall.astype(np.uint8)
    ball_c = [(20.0, 5.0 + 0.5 * t * t + 2 * t) for t in range(T)]              # falling, speeding up
    ball = _disc_track(T, H, W, ball_c, 4.0)
    shadow = _disc_track(T, H, W, [(x - 8.0, y + 6.0) for x, y in ball_c], 4.0)

    def clip(shadow_px, ball_rgb=(200.0, 30.0, 40.0)):
        frames = np.tile(wall, (T, 1, 1, 1))
        frames[shadow] = shadow_px(frames[shadow])
        frames[ball] = ball_rgb
        return frames.astype(np.uint8)

    frames = clip(lambda px: 0.6 * px)                                           # the wall in shade
    assert velocity_coupling(ball, shadow) == pytest.approx(1.0)
    assert texture_kept(shadow, frames, background) > 0.9
    assert texture_kept(ball, frames, background) == pytest.approx(0.0, abs=0.3)
    assert cast_shadows([ball, shadow], frames, background) == {1}
    assert cast_shadows([shadow], frames, background) == set()
    # a flat grey object moving with the ball: shadow-coloured, but the wall's texture is hidden
    grey = clip(lambda px: np.full_like(px, 0.6) * wall.mean(axis=(0, 1)))
    assert cast_shadows([ball, shadow], grey, background) == set()
    # a darkened patch on its own path (rising while the ball falls) is not the ball's shadow
    own = _disc_track(T, H, W, [(60.0, 70.0 - 4.0 * t) for t in range(T)], 4.0)
    f2 = np.tile(wall, (T, 1, 1, 1))
    f2[own] *= 0.6
    f2[ball] = (200.0, 30.0, 40.0)
    assert velocity_coupling(ball, own) < 0.5
    assert cast_shadows([ball, own], f2.astype(np.uint8), background) == set()
    # a companion as grey as the shadow (a grey object and a piece of it): nothing dropped
    f3 = clip(lambda px: 0.6 * px, ball_rgb=0.7 * wall.mean(axis=(0, 1)))
    assert cast_shadows([ball, shadow], f3, background) == set()


def test_untangle_shadows_gives_the_caster_back_the_frames_the_tracker_swapped():
    """dev/04: where the segmenter misses the blurred ball for a frame, the tracker carries the ball's
    identity on to its shadow and back. Once the shadow is named over the whole track, those frames
    are swapped back (and a frame where only the ball was seen, under the shadow's id, is moved),
    so the caster's track is the ball in every frame and follows its fall; the shadow track keeps
    only shadow pixels."""
    from pipeline.observe import cast_shadow_pairs, untangle_shadows

    T, H, W = 24, 130, 80
    rng = np.random.default_rng(1)
    texture = rng.normal(0.0, 12.0, (H, W, 1)) + np.linspace(-10.0, 10.0, W)[None, :, None]
    wall = np.clip(np.array([200.0, 190.0, 180.0]) + texture, 0, 255)
    background = wall.astype(np.uint8)
    ball_c = [(20.0, 5.0 + 0.15 * t * t + t) for t in range(T)]
    shadow_c = [(x + 12.0, y + 6.0) for x, y in ball_c]
    ball = _disc_track(T, H, W, ball_c, 4.0)
    shadow = _disc_track(T, H, W, shadow_c, 4.0)
    frames = np.tile(wall, (T, 1, 1, 1))
    frames[shadow] *= 0.6
    frames[ball] = (200.0, 30.0, 40.0)
    frames = frames.astype(np.uint8)
    a, b = ball.copy(), shadow.copy()          # the tracker's two ids
    for t in (4, 6):                           # swapped
        a[t], b[t] = shadow[t], ball[t]
    a[9], b[9] = False, ball[9]                # the ball seen under the shadow's id only
    pairs = cast_shadow_pairs([a, b], frames, background)
    assert pairs == {1: 0}
    assert untangle_shadows([a, b], pairs, frames, background) == 3
    assert np.array_equal(a, ball)                                   # every frame the ball's
    assert np.array_equal(b[[t for t in range(T) if t != 9]], shadow[[t for t in range(T) if t != 9]])
    assert not b[9].any()
    # the centroid now falls as the ball does: the second differences are its 0.3 px/frame^2
    ys = np.array([np.nonzero(a[t])[0].mean() for t in range(T)])
    assert np.allclose(np.diff(ys, 2), 0.3, atol=0.5)
    assert np.abs(np.diff(ys, 2)).max() < 1.0      # before: jumps of 2x the 12 px between the two
    assert untangle_shadows([a, b], {}, frames, background) == 0     # nothing named, nothing moved


def test_velocity_coupling_ignores_a_few_swapped_steps():
    """Where a tracker swaps two nearby tracks for a frame, those steps point the wrong way; the
    share of steps that agree still reads the two as moving together."""
    from pipeline.observe import velocity_coupling

    T, H, W = 16, 100, 60
    a_c = [(20.0, 5.0 + 5.0 * t) for t in range(T)]
    b_c = [(40.0, 10.0 + 5.0 * t) for t in range(T)]
    a_c[6], b_c[6] = b_c[6], a_c[6]                                      # one frame swapped
    a, b = _disc_track(T, H, W, a_c, 3.0), _disc_track(T, H, W, b_c, 3.0)
    assert velocity_coupling(a, b) >= 0.8
    still = _disc_track(T, H, W, [(30.0, 50.0)] * T, 3.0)
    assert velocity_coupling(a, still) == 0.0                            # no steps where both move


def test_flow_agreement_distrusts_the_flow_where_it_misses_the_masks_motion():
    """A small ball falling more than its size per frame: the masks step 20 px down, while the flow
    estimator (here as DIS does on dev/04's fall) reads it still. Those pixels are not trusted and
    the search's EPE skips them; where the flow follows the masks (the slow frames) it is kept, and
    so is the background. An EPE computed against the gated flow charges a re-simulation that
    moves as the masks do nothing on the frames the estimator missed."""
    from pipeline.metrics import flow_epe
    from pipeline.observe import flow_agreement

    T, H, W = 6, 120, 40
    centres = [(20.0, 10.0 + 4.0 * t) for t in range(3)] + [(20.0, 18.0 + 20.0 * (t - 1)) for t in range(3, T)]
    seg = np.where(_disc_track(T, H, W, centres, 4.0), 0, -1).astype(np.int8)
    flow = np.zeros((T - 1, H, W, 2), np.float32)
    true_flow = np.zeros_like(flow)
    for t in range(T - 1):
        step = np.subtract(centres[t + 1], centres[t])
        true_flow[t][seg[t] == 0] = step
        if step[1] < 10:                                   # the estimator follows slow steps only
            flow[t][seg[t] == 0] = step
    ok = flow_agreement(seg, flow)
    slow = [t for t in range(T - 1) if centres[t + 1][1] - centres[t][1] < 10]
    fast = [t for t in range(T - 1) if t not in slow]
    assert slow and fast
    assert all(ok[t][seg[t] == 0].all() for t in slow)
    assert not any(ok[t][seg[t] == 0].any() for t in fast)
    assert ok[:, seg.max(axis=0) < 0].all()                # the background is always trusted
    gated = np.where(ok[..., None], flow, np.nan)
    fg = seg[:-1] >= 0
    assert flow_epe(true_flow, gated, fg, fg, over="observed") == pytest.approx(0.0)
    assert flow_epe(true_flow, flow, fg, fg, over="observed") > 5.0


class _TruthSegmenter:
    """A stand-in segmenter that marks the true masks of chosen objects (probability 0.99) and
    no contact: what a network that sees exactly those objects would give."""

    def __init__(self, seg: np.ndarray, ids: tuple[int, ...]) -> None:
        self.fg = np.isin(seg, ids).astype(np.float32) * 0.99

    def __call__(self, frames, background, batch: int = 16):
        return self.fg.copy(), np.zeros_like(self.fg)


def test_a_second_segmenter_adds_the_object_at_rest_the_first_missed_and_nothing_it_saw():
    """``hybrid_objects(..., rest_segmenter=)``: a ball rolls past a box that never moves. A first
    segmenter that sees only the ball gives one object; a second that sees both adds the box at
    rest (whole, after the mover) and not the ball again (its pixels are explained already)."""
    from pipeline.metrics import observation_scores
    from pipeline.observe import hybrid_objects

    fr = _box_at_rest_and_rolling_ball()
    first, second = _TruthSegmenter(fr.seg, (1,)), _TruthSegmenter(fr.seg, (0, 1))
    alone = observation_scores(fr.seg, hybrid_objects(fr.rgb, fr.rgb, 4, segmenter=first), [True, False])
    kinds, cands = [], []
    seg = hybrid_objects(fr.rgb, fr.rgb, 4, kinds, first, cands, rest_segmenter=second)
    both = observation_scores(fr.seg, seg, [True, False])
    assert alone["n_pred"] == 1 and alone["still_found"] == 0.0, alone["per_object"]
    assert both["n_pred"] == 2 and both["still_iou"] >= 0.95, both["per_object"]
    assert both["moving_iou"] == pytest.approx(alone["moving_iou"])
    assert [k["kind"] for k in kinds] == ["mover", "at_rest"]
    assert [c.get("second", False) for c in cands] == [False, True]     # one second-opinion candidate: the box


@pytest.mark.skipif(not DEFAULT_WEIGHTS.exists(), reason="no shipped segmenter weights")
def test_realvideo_rest_segmenter_weights_load_before_any_video_and_name_the_field(tmp_path):
    """realvideo.rest_segmenter_weights: null asks no second network; wide loads the wide one;
    a missing file stops `dynamics infer` in one line naming the field, before any output."""
    from pipeline import segmenter as S
    from pipeline.params import ParamsError, load_params
    from pipeline.reconstruct import observation_segmenters, reconstruct
    params = load_params(None)
    params["realvideo"]["rest_segmenter_weights"] = None
    assert observation_segmenters(params)[1] is None
    params["realvideo"]["rest_segmenter_weights"] = "wide"
    assert Path(observation_segmenters(params)[1].path) == S.WIDE_WEIGHTS
    params["realvideo"]["rest_segmenter_weights"] = str(tmp_path / "missing.pt")
    with pytest.raises(ParamsError, match=r"realvideo\.rest_segmenter_weights: .*missing\.pt: no segmenter checkpoint"):
        reconstruct(tmp_path / "no_video.mp4", tmp_path / "out", params)
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif(not DEFAULT_WEIGHTS.exists(), reason="no shipped segmenter weights")
def test_the_wide_network_finds_an_object_at_rest_seen_from_above_that_the_shipped_one_misses(tmp_path):
    """A rendered clip with true masks (truth set MuJoCo seed 0, clip 20; camera pitch 75 deg): two
    objects move and one lies at rest throughout. The shipped segmenter never marks the one at
    rest (objects at rest seen from above, ``reports/segmenter_recall.md``); asked as the second
    opinion (``rest_segmenter``), the wide network finds it whole, and the movers' masks are the
    same as without it."""
    from pipeline.metrics import observation_scores
    from pipeline.observe import observe, truth_in_window
    from pipeline.segmenter import WIDE_WEIGHTS, shipped
    from pipeline.truthsets import mujoco_scenes
    from pipeline.truthsets.common import generate_clip, write_clip
    clip = generate_clip(mujoco_scenes, seed=0, index=20)
    folder = write_clip(tmp_path / "clip", clip)
    scores = {}
    for rest in (None, shipped(WIDE_WEIGHTS)):
        obs = observe(folder / "video.mp4", clip.fps, None, 30, 1.0, mask_method="hybrid", rest_segmenter=rest)
        truth, frames = truth_in_window(clip.seg, obs)
        still = np.linalg.norm(clip.pos[frames] - clip.pos[frames][:1], axis=-1).max(axis=0) < 0.005
        s = observation_scores(truth, obs.seg, list(still))
        scores[rest is not None] = ({o["true"]: o["iou"] for o in s["per_object"]}, s["n_pred"])
    assert list(still).count(True) == 1
    at_rest = int(np.argmax(still))
    before, after = scores[False][0], scores[True][0]
    assert scores[False][1] == 2 and before.get(at_rest, 0.0) == 0.0, scores
    assert scores[True][1] == 3 and after[at_rest] >= 0.85, scores
    assert all(after[k] == pytest.approx(before[k]) for k in before if k != at_rest), scores


def test_skin_like_passes_skin_tones_light_to_dark_and_not_other_colours():
    """Chai & Ngan's YCrCb box and Kovac's RGB rule together: light, medium and dark skin pass; grey,
    white, green, blue and a saturated red do not."""
    from pipeline.masks import skin_like

    skin = [(255, 224, 196), (224, 172, 140), (198, 134, 66), (141, 85, 36)]
    other = [(128, 128, 128), (255, 255, 255), (30, 200, 40), (40, 60, 220), (255, 0, 0)]
    img = np.asarray([skin + other], np.uint8)             # (1, 9, 3): one row of pixels
    assert skin_like(img)[0].tolist() == [True] * len(skin) + [False] * len(other)
    stack = np.repeat(img[None], 3, axis=0)                 # (T, H, W, 3) gives (T, H, W)
    assert skin_like(stack).shape == (3, 1, len(skin) + len(other))


def test_hands_drop_an_arm_reaching_in_and_keep_objects_at_the_border_or_skin_toned():
    """An arm reaching in from the bottom edge (skin-toned, on the border in every frame) is a hand;
    a skin-toned ball wholly in view is an object, and so is a blue box that slides in from the
    left edge and stays cut by it (on the border in every frame, but not skin)."""
    from pipeline.observe import hands

    T, H, W = 8, 48, 64
    frames = np.full((T, H, W, 3), 120, np.uint8)
    arm, ball, box = (np.zeros((T, H, W), bool) for _ in range(3))
    for t in range(T):
        arm[t, H - 10 - 2 * t:, 40:48] = True               # rises from the bottom edge
        ball[t, 10:16, 8 + 3 * t:14 + 3 * t] = True          # crosses the view, never at the border
        box[t, 30:38, 0:4 + t] = True                        # enters from the left edge
    frames[arm] = (224, 172, 140)
    frames[ball] = (198, 134, 66)
    frames[box] = (40, 60, 220)
    assert hands([arm, ball, box], frames) == {0}
    assert hands([ball, box], frames) == set()


@pytest.mark.skipif(not DEFAULT_WEIGHTS.exists() or not (REAL / "dev" / "08_ball_vertical_toss.mp4").exists(),
                    reason="no shipped segmenter weights or no shared real clips")
def test_the_hand_that_tosses_a_ball_is_not_an_object_on_a_real_clip():
    """dev/08: a hand tosses a ball up from the bottom of the view. The segmenter tracks the hand as
    a mover (it moves, the network is sure of it); it is dropped as a hand (on the border in every
    frame where it is seen, skin-toned), and the ball, in flight wholly inside the view, is kept."""
    from pipeline.observe import observe, scene_rate

    video = REAL / "dev" / "08_ball_vertical_toss.mp4"
    found: list[dict] = []
    obs = observe(video, None, None, scene_rate(video, None, 30), 1.0, mask_method="hybrid", candidates=found)
    dropped = [c for c in found if c.get("dropped") == "hand"]
    assert dropped and all(c["border"] >= 0.8 for c in dropped)
    kept_movers = [c for c in found if c.get("kept") and c["decision"] == "mover"]
    assert len(kept_movers) == 1 and kept_movers[0]["border"] <= 0.2 and kept_movers[0]["travel"] >= 2.0
    assert obs.moving_flags.count(True) == 1


def test_objects_at_rest_no_mover_touches_are_scenery_and_a_struck_or_touched_one_stays():
    """A ball rolls along a row of objects at rest: the one it stops against (its mask reaches
    the ball's) stays, the one it passes within its own step of between two frames stays (the
    contact may fall between them), the one far above its path is scenery. With no mover every
    object stays. ``without_scenery`` renumbers what is left and keeps the moving flags."""
    from pipeline.observe import Observation, untouched_at_rest, without_scenery

    T, H, W = 12, 60, 120
    seg = np.full((T, H, W), -1, np.int8)
    seg[:, 2:10, 100:110] = 0                            # far above the path: scenery
    for t in range(T):                                    # ball 10 px wide, 6 px / frame, stops at x = 70
        x = min(4 + 6 * t, 60)
        seg[t, 40:50, x:x + 10] = 1
    seg[:, 38:52, 70:80] = 2                             # the wall it stops against (touching)
    seg[:, 30:36, 30:40] = 3                             # 4 px above its path: within one step of 6 px
    moving = (False, True, False, False)
    assert untouched_at_rest(seg, moving) == [0]
    assert untouched_at_rest(seg, (False, False, False, False)) == []

    obs = Observation(frames=None, seg=seg, flow=None, clip=None, start=0.0, auto=True, crop=(0, 0, W, H),
                      size=(W, H), scene_fps=30, flow_method="dis", mask_method="hybrid", moving=moving)
    kept, dropped = without_scenery(obs)
    assert dropped == [0] and kept.moving == (True, False, False)
    assert kept.seg.max() == 2 and (kept.seg[0, 2:10, 100:110] == -1).all()
    assert np.array_equal(kept.seg == 0, seg == 1) and np.array_equal(kept.seg == 1, seg == 2)
    same, none = without_scenery(Observation(frames=None, seg=seg, flow=None, clip=None, start=0.0, auto=True,
                                             crop=(0, 0, W, H), size=(W, H), scene_fps=30, flow_method="dis",
                                             mask_method="median", moving=None))
    assert none == [] and same.seg is seg


def test_an_attached_cast_shadow_is_cut_from_the_mask_a_grey_or_dark_object_is_not():
    """dev/11: a ball rolling on a textured table, lit from above, casts a shadow that touches it;
    the segmenter marks ball and shadow as one mask. The shadow (the table darkened, its texture
    still there) is cut, leaving the ball's disc (all of it, and under 15 % of the crescent); kept whole: the same mask where that part is a
    flat grey piece of the object (it hides the texture), and a dark object's mask (no part of it
    looks like the table in shade)."""
    from pipeline.observe import attached_shadows

    T, H, W = 10, 80, 100
    rng = np.random.default_rng(1)
    texture = rng.normal(0.0, 12.0, (H, W, 1)) + np.linspace(-10.0, 10.0, W)[None, :, None]
    table = np.clip(np.array([170.0, 170.0, 165.0]) + texture, 0, 255)
    background = table.astype(np.uint8)
    centres = [(20.0 + 5 * t, 35.0) for t in range(T)]
    ball = _disc_track(T, H, W, centres, 8.0)
    shade = _disc_track(T, H, W, [(x + 3.0, y + 7.0) for x, y in centres], 8.0) & ~ball

    def clip(shade_px, ball_rgb=(200.0, 210.0, 40.0)):
        frames = np.tile(table, (T, 1, 1, 1))
        frames[shade] = shade_px(frames[shade])
        frames[ball] = ball_rgb
        return frames.astype(np.uint8)

    seg = np.where(ball | shade, 0, -1).astype(np.int8)
    out, trimmed = attached_shadows(seg, clip(lambda px: 0.55 * px), background)
    assert trimmed == [0]
    iou = ((out == 0) & ball).sum() / ((out == 0) | ball).sum()
    assert iou > 0.93 and (out[shade] == 0).mean() < 0.15   # the crescent's thin tips may stay (3x3 opening)
    assert (out[ball] == 0).all()
    grey = clip(lambda px: np.full_like(px, 0.55) * table.mean(axis=(0, 1)))
    assert attached_shadows(seg, grey, background)[1] == []
    dark = clip(lambda px: 0.55 * px, ball_rgb=(25.0, 25.0, 25.0))
    only_dark = np.where(ball, 0, -1).astype(np.int8)
    out, trimmed = attached_shadows(only_dark, dark, background)
    assert trimmed == [] and np.array_equal(out, only_dark)


def test_on_a_flat_surface_a_coloured_objects_attached_shadow_is_cut_a_grey_objects_part_is_not():
    """Real clip 01: a green ball bouncing on a plain floor; its shadow touches it, and the floor has no
    texture for the texture test to find kept or hidden. There the shadow (the floor's colour,
    darker) is cut because the rest of the mask has a colour of its own; a grey object of the
    floor's colour keeps its darker part (nothing tells that part from the object), and so does a
    coloured object on a textured floor whose dark part hides the texture (the test above)."""
    from pipeline.observe import attached_shadows, flat_surface, own_colour

    T, H, W = 10, 80, 100
    rng = np.random.default_rng(2)
    floor = np.clip(np.array([150.0, 150.0, 145.0]) + rng.normal(0.0, 0.6, (H, W, 3)), 0, 255)
    background = floor.astype(np.uint8)
    centres = [(20.0 + 5 * t, 35.0) for t in range(T)]
    ball = _disc_track(T, H, W, centres, 8.0)
    shade = _disc_track(T, H, W, [(x + 3.0, y + 7.0) for x, y in centres], 8.0) & ~ball
    seg = np.where(ball | shade, 0, -1).astype(np.int8)

    def clip(ball_rgb):
        frames = np.tile(floor, (T, 1, 1, 1))
        frames[shade] = 0.55 * frames[shade]
        frames[ball] = ball_rgb
        return frames.astype(np.uint8)

    assert flat_surface(shade, background)
    green = clip((60.0, 170.0, 50.0))
    assert own_colour(ball | shade, shade, seg, green) > 0.2
    out, trimmed = attached_shadows(seg, green, background)
    assert trimmed == [0]
    assert (out[ball] == 0).all() and (out[shade] == 0).mean() < 0.15
    grey = clip((180.0, 180.0, 174.0))          # the floor's chromaticity, lighter
    assert own_colour(ball | shade, shade, seg, grey) < 0.02
    out, trimmed = attached_shadows(seg, grey, background)
    assert trimmed == [] and np.array_equal(out, seg)


def test_a_shadow_whose_caster_is_out_of_view_is_not_an_object():
    """dev/02: a patch of the table darkened for 9 frames (the shadow of something out of the
    view) was tracked as a mover and fitted as a second object. Through a shadow the surface's
    texture shows, which no object does: a darkened patch on its own path is dropped with no
    caster in view; a flat grey object on the same path, a red ball, and a shadow's caster are not."""
    from pipeline.observe import lone_shadows

    T, H, W = 12, 80, 80
    rng = np.random.default_rng(2)
    texture = rng.normal(0.0, 12.0, (H, W, 1)) + np.linspace(-10.0, 10.0, W)[None, :, None]
    wall = np.clip(np.array([200.0, 190.0, 180.0]) + texture, 0, 255)
    background = wall.astype(np.uint8)
    ball = _disc_track(T, H, W, [(20.0, 5.0 + 5 * t) for t in range(T)], 4.0)
    own = _disc_track(T, H, W, [(60.0, 70.0 - 4.0 * t) for t in range(T)], 5.0)
    frames = np.tile(wall, (T, 1, 1, 1))
    frames[own] *= 0.6
    frames[ball] = (200.0, 30.0, 40.0)
    assert lone_shadows([ball, own], frames.astype(np.uint8), background) == {1}
    assert lone_shadows([ball, own], frames.astype(np.uint8), background, casters={1}) == set()
    grey = np.tile(wall, (T, 1, 1, 1))
    grey[own] = 0.6 * wall.mean(axis=(0, 1))
    grey[ball] = (200.0, 30.0, 40.0)
    assert lone_shadows([ball, own], grey.astype(np.uint8), background) == set()


def test_a_mover_that_comes_and_goes_mid_view_vanishes_one_that_enters_does_not():
    """A rigid body in view does not vanish: a track seen in 9 of 30 frames in the middle of the
    view (dev/02's faint shadow under a bouncing ball) is not an object; one seen as rarely that
    enters through the border, or one seen in most frames, is."""
    from pipeline.observe import VANISH_SEEN, filled_in, vanishes

    T, H, W = 30, 60, 80
    yy, xx = np.mgrid[:H, :W]

    def disc(cx, cy, r=5):
        return (xx - cx) ** 2 + (yy - cy) ** 2 <= r * r

    flicker = np.zeros((T, H, W), bool)
    for t in (4, 5, 6, 7, 9, 10, 13, 14, 15):                  # 0.3 of the window, never at the border
        flicker[t] = disc(40, 45)
    assert flicker.any(axis=(1, 2)).mean() < VANISH_SEEN and vanishes(flicker)
    entering = np.zeros((T, H, W), bool)
    for t in range(21, T):                                      # slides in from the right edge
        entering[t] = disc(W + 2 - 4 * (t - 21), 30)
    assert entering.any(axis=(1, 2)).mean() < VANISH_SEEN and not vanishes(entering)
    steady = np.zeros((T, H, W), bool)
    for t in range(0, T, 2):                                    # half the frames, mid-view
        steady[t] = disc(20 + t, 30)
    assert not vanishes(steady)
    # the frames the segmenter missed and background subtraction saw count as seen
    bs = np.full((T, H, W), -1, np.int8)
    for t in range(T):
        bs[t][disc(40, 45)] = 0
    assert not vanishes(filled_in(flicker, [0], bs))
    assert filled_in(flicker, [], bs).sum() == flicker.sum()
