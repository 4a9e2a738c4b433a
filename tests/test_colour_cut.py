"""Touching objects of different colours are cut apart; one object with shading or a checker
texture is not (pipeline.masks.cut_by_colour, issue 36)."""

import cv2
import numpy as np

from pipeline.masks import cut_by_colour, majority_smooth, solidity


def _components(mask: np.ndarray) -> int:
    return cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)[0] - 1


def _scene():
    """A grey floor, canvas (120, 160)."""
    return np.full((120, 160, 3), 128, np.uint8), np.zeros((120, 160), bool)


def test_two_touching_discs_of_different_colours_become_two_parts():
    frame, mask = _scene()
    for (cx, colour) in ((60, (40, 160, 40)), (95, (40, 40, 170))):      # green and blue, touching
        disc = np.zeros_like(mask, np.uint8)
        cv2.circle(disc, (cx, 60), 18, 1, -1)
        mask |= disc > 0
        frame[disc > 0] = colour
    assert _components(mask) == 1
    out = cut_by_colour(mask, frame, min_area=30)
    assert _components(out) == 2
    assert out.sum() >= 0.9 * mask.sum()                                 # only the seam is removed
    assert not (out & ~mask).any()


def test_a_shaded_sphere_is_one_object():
    frame, mask = _scene()
    yy, xx = np.mgrid[0:120, 0:160]
    disc = (xx - 80) ** 2 + (yy - 60) ** 2 <= 30 ** 2
    shade = np.clip(1.2 - ((xx - 65) ** 2 + (yy - 45) ** 2) / 2500.0, 0.15, 1.2)   # lit top-left, dark rim
    base = np.array([200, 60, 40], np.float32)
    frame[disc] = np.clip(base[None] * shade[disc][:, None], 0, 255).astype(np.uint8)
    mask |= disc
    np.testing.assert_array_equal(cut_by_colour(mask, frame, min_area=30), mask)


def test_a_checkered_box_is_one_object():
    frame, mask = _scene()
    mask[30:90, 50:110] = True
    yy, xx = np.mgrid[0:120, 0:160]
    check = ((yy // 10 + xx // 10) % 2).astype(bool)
    frame[mask & check] = (220, 40, 40)
    frame[mask & ~check] = (40, 40, 220)
    np.testing.assert_array_equal(cut_by_colour(mask, frame, min_area=30), mask)


def test_a_convex_object_of_two_colours_is_one_object():
    """A cube seen with a yellow top and a red side (a Rubik's cube): the component is convex,
    so its colours do not make it two objects; the same colours as two touching discs do."""
    frame, mask = _scene()
    mask[30:90, 50:110] = True
    frame[30:55, 50:110] = (230, 210, 30)
    frame[55:90, 50:110] = (200, 40, 40)
    np.testing.assert_array_equal(cut_by_colour(mask, frame, min_area=30), mask)


def test_solidity_of_convex_and_waisted_shapes():
    disc = np.zeros((120, 160), np.uint8)
    cv2.circle(disc, (80, 60), 25, 1, -1)
    assert solidity(disc) > 0.97
    two = np.zeros_like(disc)
    cv2.circle(two, (60, 60), 18, 1, -1)
    cv2.circle(two, (96, 60), 18, 1, -1)
    assert solidity(two) < 0.9


def test_the_cut_does_not_depend_on_earlier_random_draws():
    """``cv2.kmeans`` draws its k-means++ centres from the thread's RNG, whose state carries over from
    earlier calls. The cut seeds it first: whatever state the RNG was left in, the k-means starts from
    the same one (the draws right after the cut agree) and the cut is the same."""
    frame, mask = _scene()
    for (cx, colour) in ((60, (40, 160, 40)), (95, (40, 40, 170))):      # non-convex: k-means runs
        disc = np.zeros_like(mask, np.uint8)
        cv2.circle(disc, (cx, 60), 18, 1, -1)
        mask |= disc > 0
        frame[disc > 0] = colour
    cuts, after = [], []
    for seed in range(4):
        cv2.setRNGSeed(1000 + seed)                      # as if other code had drawn before
        cuts.append(cut_by_colour(mask, frame, min_area=30))
        draw = np.zeros(4, np.float32)
        cv2.randu(draw, 0.0, 1.0)
        after.append(draw)
    for c, d in zip(cuts[1:], after[1:]):
        np.testing.assert_array_equal(c, cuts[0])
        np.testing.assert_array_equal(d, after[0])


def test_majority_smooth_is_blind_to_the_label_numbering():
    """Swapping labels 1 and 2 swaps the vote's result; a lone pixel inside the other label flips;
    pixels off ``lit`` are 0."""
    rng = np.random.default_rng(0)
    lit = np.zeros((40, 50), bool)
    cv2.circle(lit.view(np.uint8), (25, 20), 15, 1, -1)
    part = np.where(lit, rng.integers(1, 3, lit.shape), 0).astype(np.uint8)
    swapped = np.where(lit, 3 - part, 0).astype(np.uint8)
    a, b = majority_smooth(part, lit), majority_smooth(swapped, lit)
    np.testing.assert_array_equal(b, np.where(lit, 3 - a, 0))
    assert not a[~lit].any()
    block = np.where(lit, 1, 0).astype(np.uint8)
    block[20, 25] = 2
    assert majority_smooth(block, lit)[20, 25] == 1


def test_the_cut_does_not_depend_on_which_cluster_kmeans_numbers_first(monkeypatch):
    """Two touching discs, a tenth of each disc's pixels the other's colour: the cut is the same
    whether k-means calls the green disc cluster 0 or cluster 1 (a median filter of the label image
    favoured label 1 at the edge, and the cuts differed by 100-150 px)."""
    rng = np.random.default_rng(0)
    frame, mask = _scene()
    colours = [(40, 150, 50), (50, 60, 160)]
    for i, cx in enumerate((60, 93)):
        disc = np.zeros_like(mask, np.uint8)
        cv2.circle(disc, (cx, 60), 18, 1, -1)
        disc = disc > 0
        mask |= disc
        speck = rng.random(disc.shape) < 0.1
        frame[disc & ~speck] = colours[i]
        frame[disc & speck] = colours[1 - i]
    first = cut_by_colour(mask, frame, min_area=30)
    kmeans = cv2.kmeans

    def swapped(*args, **kwargs):
        compactness, assign, centres = kmeans(*args, **kwargs)
        return compactness, 1 - assign, centres[::-1].copy()

    monkeypatch.setattr(cv2, "kmeans", swapped)
    second = cut_by_colour(mask, frame, min_area=30)
    assert _components(first) == 2
    np.testing.assert_array_equal(first, second)
