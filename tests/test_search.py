"""Tests for pipeline.search: fast in-place evaluation equals rebuilding the model, fitness,
Best@K, CMA-ES refinement, the search space and the trivial baseline."""

import math
import re

import mujoco
import numpy as np
import pytest
from pydantic import ValidationError

from pipeline.metrics import sequence_iou
from pipeline.mjcf import compile_model
from pipeline.render import render_scene
from pipeline.scene import Scene
from pipeline.search import (
    SceneEvaluator, SearchConfig, SearchSpace, baseline_scene, best_of_k, cmaes_refine, evaluate_scene,
    SHAPE_DOF, fitness, floor_height, simplest_within, structure_key,
)

W, H = 48, 32


def _scene(**changes) -> Scene:
    """Three objects big in a 48x32 view, 0.4 s (12 frames)."""
    data = {
        "duration": 0.4,
        "camera": {"height": 1.0, "pitch": 35.0, "fov": 45.0},
        "objects": [
            {"shape": "box", "size": {"width": 0.25, "depth": 0.2, "height": 0.15}, "mass": 0.8,
             "position": [-0.2, -0.8, 0.075], "linear_velocity": [0.6, 0.3, 0.0]},
            {"shape": "sphere", "size": {"radius": 0.1}, "mass": 0.3, "position": [0.2, -0.7, 0.3],
             "linear_velocity": [-0.4, 0.0, 1.0], "material": {"sliding_friction": 0.3, "damping": 0.05}},
            {"shape": "cylinder", "size": {"radius": 0.08, "height": 0.2}, "mass": 0.5,
             "position": [0.05, -0.4, 0.1], "angular_velocity": [0.0, 0.0, 4.0]},
        ],
    }
    data.update(changes)
    return Scene.from_dict(data)


def _edit(scene: Scene, i: int, **fields) -> Scene:
    d = scene.model_dump()
    d["objects"][i].update(fields)
    return Scene.from_dict(d)


# ----------------------------------------------------------------------- fast == naive
def _candidates(base: Scene) -> dict[str, Scene]:
    return {
        "size": _edit(_edit(base, 0, size={"width": 0.3, "depth": 0.15, "height": 0.2}, position=[-0.2, -0.8, 0.1]),
                      1, size={"radius": 0.13}),
        "mass+material": _edit(_edit(base, 1, mass=2.0, material={"sliding_friction": 0.9, "rolling_friction": 0.01,
                                                                   "damping": 0.5}), 0, mass=0.2),
        "camera+gravity": base.replace(camera={"height": 1.3, "pitch": 40.0, "fov": 52.0}, gravity=7.0),
        "velocity+orientation": _edit(_edit(base, 0, linear_velocity=[-0.5, 1.0, 0.5], angular_velocity=[0, 2, 0]),
                                      2, orientation=[0.9239, 0.3827, 0.0, 0.0]),
        "six_dof_camera": base.replace(camera={"position": [0.3, -1.9, 1.1], "yaw": 8.0, "pitch": 30.0,
                                               "roll": 3.0, "fov": 48.0}),
    }


def test_fast_evaluator_equals_rebuilding_the_model():
    base = _scene()
    cands = _candidates(base)
    with SceneEvaluator(base, W, H) as ev:
        for name, cand in [*cands.items(), ("base again", base)]:
            seg, flow = ev.evaluate(cand)
            naive_model = compile_model(cand)
            # the edited model equals the compiled one in every field that the edits touch
            # (a plane's third size is only its rendering grid spacing, which the evaluator
            # coarsens: compare the physical sizes)
            planes = naive_model.geom_type == mujoco.mjtGeom.mjGEOM_PLANE
            np.testing.assert_allclose(ev.model.geom_size[~planes], naive_model.geom_size[~planes], err_msg=name)
            np.testing.assert_allclose(ev.model.geom_size[planes, :2], naive_model.geom_size[planes, :2], err_msg=name)
            for field in ("body_mass", "body_inertia", "body_invweight0", "dof_invweight0", "dof_M0",
                          "geom_rbound", "geom_aabb", "bvh_aabb", "geom_friction", "dof_damping",
                          "key_qpos", "key_qvel", "qpos0", "cam_pos", "cam_quat", "cam_fovy", "cam_pos0",
                          "cam_mat0", "body_subtreemass", "dof_length"):
                np.testing.assert_allclose(getattr(ev.model, field), getattr(naive_model, field),
                                           rtol=1e-9, atol=1e-12, err_msg=f"{name}: {field}")
            np.testing.assert_allclose(ev.model.opt.gravity, naive_model.opt.gravity)
            for stat in ("meanmass", "meaninertia", "meansize", "extent", "center"):
                np.testing.assert_allclose(getattr(ev.model.stat, stat), getattr(naive_model.stat, stat),
                                           rtol=1e-9, err_msg=f"{name}: stat.{stat}")
            _, frames = render_scene(cand, W, H, rgb=False, depth=False)
            assert sequence_iou(frames.seg, seg)["full_iou"] == 1.0, name
            np.testing.assert_array_equal(seg, frames.seg, err_msg=name)
            np.testing.assert_allclose(flow, frames.flow, atol=1e-4, err_msg=name)


def test_fast_evaluator_with_an_effect():
    """Effects belong to the structure; in-place edits keep them (quadratic drag uses the
    edited masses and inertias at run time)."""
    drag = _scene(effects=[{"effect": "quadratic_drag", "parameters": {"density": 40.0}}])
    cand = _edit(drag, 1, size={"radius": 0.14}, mass=0.1, linear_velocity=[-1.0, 0.5, 2.0])
    with SceneEvaluator(drag, W, H) as ev:
        seg, flow = ev.evaluate(cand)
    _, frames = render_scene(cand, W, H, rgb=False, depth=False)
    np.testing.assert_array_equal(seg, frames.seg)
    np.testing.assert_allclose(flow, frames.flow, atol=1e-4)


def test_fast_evaluator_edits_restitution_in_place():
    """``restitution`` is edited per candidate (engine.EDITED_IN_PLACE), so the search can fit
    ``e``: one compiled model serves every ``e``, each equal to a model compiled for it, and
    different ``e`` bounce differently (the sphere falls 0.3 m onto the floor)."""
    def bouncy(e: float) -> Scene:
        return _edit(_scene(duration=0.6, effects=[{"effect": "restitution", "parameters": {"e": e}}]),
                     1, position=[0.2, -0.7, 0.4], linear_velocity=[0.0, 0.0, -1.0])

    low, high = bouncy(0.3), bouncy(0.9)
    assert structure_key(low) == structure_key(high)
    with SceneEvaluator(low, W, H) as ev:
        for cand in (high, low):
            seg, flow = ev.evaluate(cand)
            naive = compile_model(cand)
            np.testing.assert_allclose(ev.model.geom_solref, naive.geom_solref, rtol=1e-12)
            _, frames = render_scene(cand, W, H, rgb=False, depth=False)
            np.testing.assert_array_equal(seg, frames.seg)
            np.testing.assert_allclose(flow, frames.flow, atol=1e-4)
    seg_low, _ = evaluate_scene(low, W, H)
    seg_high, _ = evaluate_scene(high, W, H)
    assert sequence_iou(seg_low, seg_high)["full_iou"] < 0.99


def test_fast_evaluator_edits_a_bumpers_restitution_in_place():
    """A static geom's ``restitution`` (a springy stop) is edited per candidate like the effect's:
    one compiled model serves every value, each equal to a model compiled for it, and the search
    space frees it with ``restitution``."""
    def wall(e: float) -> Scene:
        return _edit(_scene(duration=0.6, static=[{"shape": "box", "size": {"width": 0.05, "depth": 0.6, "height": 0.3},
                                                   "position": [0.45, -0.7, 0.15], "restitution": e}]),
                     1, position=[0.2, -0.7, 0.1], linear_velocity=[1.5, 0.0, 0.0])

    low, high = wall(0.3), wall(0.9)
    assert structure_key(low) == structure_key(high) != structure_key(low.replace(static=[
        {**low.static[0].model_dump(), "restitution": None}]))
    with SceneEvaluator(low, W, H) as ev:
        for cand in (high, low):
            seg, _ = ev.evaluate(cand, flow=False)
            naive = compile_model(cand)
            np.testing.assert_allclose(ev.model.geom_solref, naive.geom_solref, rtol=1e-12)
            _, frames = render_scene(cand, W, H, rgb=False, depth=False, flow=False)
            np.testing.assert_array_equal(seg, frames.seg)
    assert "static[0].restitution" in SearchSpace(low, ("restitution",), SearchConfig().ranges).names


def test_candidates_really_differ():
    """Guard for the test above: each candidate changes the rendered clip."""
    base_seg, _ = evaluate_scene(_scene(), W, H)
    for name, cand in _candidates(_scene()).items():
        if name == "mass+material":
            continue  # mass and friction barely show in 0.4 s; checked field by field above
        seg, _ = evaluate_scene(cand, W, H)
        assert sequence_iou(base_seg, seg)["full_iou"] < 0.99, name


def test_evaluator_rejects_other_structure():
    base = _scene()
    other = base.replace(objects=[o.model_dump() for o in base.objects[:2]])
    with SceneEvaluator(base, W, H) as ev, pytest.raises(ValueError, match="structure"):
        ev.evaluate(other)


def test_evaluator_n_frames_and_no_flow():
    with SceneEvaluator(_scene(), W, H) as ev:
        seg, flow = ev.evaluate(_scene(), n_frames=5, flow=False)
    assert seg.shape == (5, H, W) and seg.dtype == np.int8 and flow is None



def test_structure_key_includes_static_geometry():
    """A different static layout (``Scene.static``: ramps, walls) is another structure, so it
    compiles a new model; duck-typed scenes so the test holds with or without ``Scene.static``."""
    from types import SimpleNamespace

    from pydantic import BaseModel

    from pipeline.search import structure_key

    class Box(BaseModel):
        kind: str = "box"
        position: tuple[float, float, float] = (0.0, 0.0, 0.0)

    base = _scene()
    plain = SimpleNamespace(objects=base.objects, effects=base.effects)
    ramp = SimpleNamespace(objects=base.objects, effects=base.effects, static=[Box(position=(0.0, 1.0, 0.0))])
    wall = SimpleNamespace(objects=base.objects, effects=base.effects, static=[Box(position=(1.0, 0.0, 0.0))])
    same = SimpleNamespace(objects=base.objects, effects=base.effects, static=[Box(position=(0.0, 1.0, 0.0))])
    empty = SimpleNamespace(objects=base.objects, effects=base.effects, static=[])
    assert structure_key(base) == structure_key(plain) == structure_key(empty)
    assert structure_key(ramp) == structure_key(same)
    assert len({structure_key(plain), structure_key(ramp), structure_key(wall)}) == 3

# ----------------------------------------------------------------------------- fitness
def test_fitness_of_the_truth():
    seg, flow = evaluate_scene(_scene(), W, H)
    f = fitness(seg, flow, seg, flow, SearchConfig(lambda_epe=1.0))
    assert f["full_iou"] == 1.0 and f["epe"] == 0.0 and f["fitness"] == 1.0


def test_fitness_weights_and_foreground_only_observation():
    seg, flow = evaluate_scene(_scene(), W, H)
    obs_flow = flow + np.float32(1.0)                     # EPE sqrt(2) on the foreground
    f = fitness(seg, flow, seg, obs_flow, SearchConfig(lambda_epe=0.5, prior_weight=2.0), prior=0.1)
    assert f["epe"] == pytest.approx(math.sqrt(2), rel=1e-6)
    assert f["fitness"] == pytest.approx(1.0 - 0.5 * math.sqrt(2) - 0.2, rel=1e-6)
    # pseudo masks without identities: foreground IoU; relabelling objects changes nothing
    relabelled = np.where(seg >= 0, 0, -1).astype(np.int8)
    f = fitness(relabelled, None, seg >= 0, None, SearchConfig())
    assert f["full_iou"] == 1.0 and math.isnan(f["epe"])


def test_fitness_strict_iou_gives_no_credit_for_a_missing_object():
    # the observation sees object 0 only in its first frame; a candidate without any object 0
    # earns 0 for it under the strict fitness, and the free credit of the frames where both are
    # absent under all_frames (issue 29 item 7)
    seg, flow = evaluate_scene(_scene(), W, H)
    obs = seg.copy()
    obs[1:][obs[1:] == 0] = -1
    pred = np.where(seg == 0, -1, seg).astype(np.int8)
    strict = fitness(pred, None, obs, None, SearchConfig(penalize_extra=False))
    old = fitness(pred, None, obs, None, SearchConfig(penalize_extra=False, fitness_iou="all_frames"))
    n = int(seg.max()) + 1
    assert strict["fitness"] == pytest.approx((n - 1) / n) == pytest.approx(strict["strict_iou"])
    assert old["fitness"] == pytest.approx(old["full_iou"]) and old["fitness"] > strict["fitness"] + 0.5 / n
    # the strict fitness prefers the candidate that shows object 0 where it is seen
    assert fitness(seg, None, obs, None, SearchConfig(penalize_extra=False))["fitness"] > strict["fitness"]
    with pytest.raises(ValidationError):
        SearchConfig(fitness_iou="both")


def test_fitness_epe_over_observed_pixels_cannot_be_lowered_by_a_far_still_object():
    """A real drop (dev/03, issue 29): a candidate that shows a large still object away from the
    motion got a lower union EPE than one that overlaps the falling object with a rougher flow,
    and won Best@K at IoU 0. Over the observed pixels its EPE is the whole observed motion."""
    T, Hh, Ww = 3, 10, 10
    obs = np.full((T, Hh, Ww), -1, np.int8)
    obs[:, 0:2, 0:2] = 0                                # 4 px object moving at 4 px/frame
    obs_flow = np.zeros((T - 1, Hh, Ww, 2), np.float32)
    obs_flow[:, 0:2, 0:2, 1] = 4.0
    far = np.full_like(obs, -1)
    far[:, 4:10, 4:10] = 0                              # 36 px, still, no overlap
    far_flow = np.zeros_like(obs_flow)
    near = np.full_like(obs, -1)
    near[:, 0:2, 0:1] = 0                               # half the object, flow 2 px/frame off
    near_flow = np.zeros_like(obs_flow)
    near_flow[:, 0:2, 0:1, 1] = 2.0
    union, observed = SearchConfig(lambda_epe=0.2), SearchConfig(lambda_epe=0.2, epe_pixels="observed")
    # union EPE: far (4 x 4) / 40 = 0.4; near (2 x 2 + 2 x 4) / 4 = 3.0
    assert fitness(far, far_flow, obs, obs_flow, union)["epe"] == pytest.approx(0.4)
    assert fitness(near, near_flow, obs, obs_flow, union)["epe"] == pytest.approx(3.0)
    assert fitness(far, far_flow, obs, obs_flow, union)["fitness"] > fitness(near, near_flow, obs, obs_flow, union)["fitness"]
    # observed EPE: far 4.0 (nothing explained), near 3.0; IoU 0 vs 0.5 decides
    f_far, f_near = fitness(far, far_flow, obs, obs_flow, observed), fitness(near, near_flow, obs, obs_flow, observed)
    assert f_far["epe"] == pytest.approx(4.0) and f_near["epe"] == pytest.approx(3.0)
    assert f_near["fitness"] == pytest.approx(0.5 - 0.2 * 3.0) and f_far["fitness"] == pytest.approx(-0.2 * 4.0)
    assert f_near["fitness"] > f_far["fitness"]


def test_simplest_within_takes_fewer_shape_parameters_only_when_the_fit_cannot_tell():
    """Best@K's parsimony rule (the main job): a ball and a disc seen along its axis fit alike; the
    sphere is taken when within the margin, the fitter shape when clearly better, and candidates of
    another structure are never swapped in."""
    ball = Scene.from_dict({"duration": 1.0, "fps": 30, "camera": {"height": 1.0, "pitch": 30.0, "fov": 45.0},
                            "objects": [{"shape": "sphere", "size": {"radius": 0.05}, "mass": 0.1,
                                         "position": [0.0, 0.0, 0.05]}]})
    disc = ball.replace(objects=[{"shape": "cylinder", "size": {"radius": 0.05, "height": 0.02}, "mass": 0.1,
                                  "position": [0.0, 0.0, 0.05]}])
    two = ball.replace(objects=[o.model_dump() for o in ball.objects]
                       + [{"shape": "sphere", "size": {"radius": 0.05}, "mass": 0.1, "position": [0.3, 0.0, 0.05]}])
    sc = lambda f: {"valid": True, "fitness": f}  # noqa: E731
    cands = [disc, ball, None, two]
    assert simplest_within(cands, [sc(0.40), sc(0.39), {"valid": False, "fitness": -math.inf}, sc(0.39)], 0, 0.02) == 1
    assert simplest_within(cands, [sc(0.40), sc(0.37), {"valid": False, "fitness": -math.inf}, sc(0.40)], 0, 0.02) == 0
    assert simplest_within(cands, [sc(0.40), sc(0.39), {"valid": False, "fitness": -math.inf}, sc(0.39)], 0, 0.0) == 0
    assert SHAPE_DOF["sphere"] < SHAPE_DOF["cylinder"] < SHAPE_DOF["box"]


def test_search_config_rejects_unknown_keys():
    with pytest.raises(ValidationError):
        SearchConfig(popsize=8, typo=1)
    with pytest.raises(ValidationError):
        SearchConfig(free=["position", "colour"])


# ------------------------------------------------------------------------------ Best@K
def test_best_of_k_picks_the_truth():
    truth = _scene()
    obs_seg, obs_flow = evaluate_scene(truth, W, H)
    off = _edit(truth, 0, position=[-0.1, -0.75, 0.075])
    fov = truth.replace(camera={"height": 1.0, "pitch": 35.0, "fov": 50.0})
    fewer = truth.replace(objects=[o.model_dump() for o in truth.objects[:2]])  # another structure
    extra = truth.replace(objects=[*(o.model_dump() for o in truth.objects),
                                   {**truth.objects[1].model_dump(), "position": (-0.3, -0.5, 0.2)}])
    cands = [None, off, fewer, truth, fov, extra]
    scores, best = best_of_k(cands, obs_seg, obs_flow, SearchConfig())
    assert best == 3
    # an extra object leaves the docs/design.md §7 IoU at 1 but costs fitness (1/4 of the IoU term)
    assert scores[5]["full_iou"] == 1.0 and scores[5]["fitness"] < 0.8
    assert scores[0]["fitness"] == -math.inf and not scores[0]["valid"]
    assert scores[3]["full_iou"] == 1.0 and scores[3]["epe"] == 0.0
    assert all(s["fitness"] < scores[3]["fitness"] for i, s in enumerate(scores) if i != 3)
    assert scores[2]["full_iou"] < 0.7                    # a missing object counts 0
    scores, best = best_of_k([None, None], obs_seg, obs_flow, SearchConfig())
    assert best is None and not any(s["valid"] for s in scores)


# ------------------------------------------------------------------------------ CMA-ES
def _two_objects() -> Scene:
    return Scene.from_dict({
        "duration": 0.5,
        "camera": {"height": 1.0, "pitch": 35.0, "fov": 45.0},
        "objects": [
            {"shape": "box", "size": {"width": 0.25, "depth": 0.25, "height": 0.2}, "mass": 0.8,
             "position": [-0.15, -0.8, 0.1], "linear_velocity": [0.6, 0.3, 0.0]},
            {"shape": "sphere", "size": {"radius": 0.1}, "mass": 0.3, "position": [0.2, -0.7, 0.3],
             "linear_velocity": [-0.4, 0.0, 1.0]},
        ],
    })


def test_cmaes_recovers_a_perturbed_scene():
    truth = _two_objects()
    obs_seg, obs_flow = evaluate_scene(truth, 64, 48)
    # positions off by ~10 cm, fov off by 5 deg
    start = _edit(_edit(truth, 0, position=[-0.07, -0.74, 0.1]), 1, position=[0.13, -0.63, 0.3])
    start = start.replace(camera={"height": 1.0, "pitch": 35.0, "fov": 50.0})
    cfg = SearchConfig(popsize=8, iterations=30, free=["position", "camera"])  # sigma 0.05, IoU - 1.0 EPE
    best, history = cmaes_refine(start, obs_seg, obs_flow, cfg, seed=0)
    before = sequence_iou(obs_seg, evaluate_scene(start, 64, 48)[0])["full_iou"]
    after = sequence_iou(obs_seg, evaluate_scene(best, 64, 48)[0])["full_iou"]
    assert before < 0.5
    assert after > 0.8, f"IoU {before:.3f} -> {after:.3f}"
    assert [h["iteration"] for h in history] == list(range(31))
    assert history[-1]["evaluations"] == 1 + 8 * 30
    # the returned scene is the best one found, not a later or repaired candidate: scored afresh
    # (rebuilt model, no prior: prior_weight 0) it gets the fitness the history reports
    seg, flow = evaluate_scene(best, 64, 48)
    assert fitness(seg, flow, obs_seg, obs_flow, cfg)["fitness"] == pytest.approx(history[-1]["best_fitness"], abs=1e-6)
    assert history[-1]["best_full_iou"] == pytest.approx(after)
    assert best.composition == truth.composition


def test_cmaes_recovers_restitution_from_the_bounces():
    """``search.free: restitution`` (issue 29: the bounces of a real drop drift apart when the
    first bounce's ``e`` is a little off): a ball dropped 0.4 m bounces twice in 1 s with e =
    0.8; CMA-ES started at e = 0.65, with nothing else free and the main job's fitness, finds e
    within 0.05."""
    def drop(e: float) -> Scene:
        return Scene.from_dict({"duration": 1.0, "fps": 30, "camera": {"height": 0.25, "pitch": 0.0, "fov": 45.0},
                                "objects": [{"shape": "sphere", "size": {"radius": 0.04}, "mass": 0.1,
                                             "position": [0.0, -1.2, 0.4]}],
                                "effects": [{"effect": "restitution", "parameters": {"e": e}}]})

    obs_seg, obs_flow = evaluate_scene(drop(0.8), 48, 64)
    cfg = SearchConfig(popsize=6, iterations=8, sigma=0.2, free=["restitution"], lambda_epe=0.05,
                       epe_pixels="observed")
    best, _ = cmaes_refine(drop(0.65), obs_seg, obs_flow, cfg, seed=0)
    assert best.effects[0].parameters["e"] == pytest.approx(0.8, abs=0.05)
    before = sequence_iou(obs_seg, evaluate_scene(drop(0.65), 48, 64)[0])["strict_iou"]
    after = sequence_iou(obs_seg, evaluate_scene(best, 48, 64)[0])["strict_iou"]
    assert before < 0.6 and after > 0.85


def test_cmaes_is_deterministic_and_keeps_mass_fixed():
    truth = _scene()
    obs_seg, obs_flow = evaluate_scene(truth, W, H)
    start = _edit(truth, 1, position=[0.25, -0.7, 0.3])
    cfg = SearchConfig(popsize=4, iterations=2)
    a, ha = cmaes_refine(start, obs_seg, obs_flow, cfg, seed=3)
    b, hb = cmaes_refine(start, obs_seg, obs_flow, cfg, seed=3)
    assert a == b and ha[-1]["best_fitness"] == hb[-1]["best_fitness"]
    assert [o.mass for o in a.objects] == [o.mass for o in start.objects]
    assert [o.material for o in a.objects] == [o.material for o in start.objects]
    assert ha[-1]["evaluations"] == 9 and ha[-1]["best_fitness"] >= ha[0]["best_fitness"]


# -------------------------------------------------------------------------- search space
def test_search_space_decodes_start_and_stays_valid():
    scene = _scene()
    space = SearchSpace(scene, SearchConfig().free + ("mass", "friction", "damping", "angular_velocity"),
                        SearchConfig().ranges)
    back = space.decode(space.x0)
    for a, b in zip(back.objects, scene.objects):
        np.testing.assert_allclose(a.position, b.position, atol=1e-9)
        np.testing.assert_allclose(a.orientation, b.orientation, atol=1e-9)
        np.testing.assert_allclose(list(a.size.model_dump().values()), list(b.size.model_dump().values()), rtol=1e-9)
        assert a.mass == pytest.approx(b.mass)
    assert back.camera.fov == pytest.approx(scene.camera.fov)
    # corners of the box and random points decode to valid scenes: no centre below the start
    # object's floor contact height (the documented bound) nor below the decoded object's own
    # (its size and orientation are free as well: before issue 35 it sank up to 1.5 cm into the
    # floor at these points, and `dynamics simulate` refused the written scene), friction and
    # mass in range, shapes fixed
    rng = np.random.default_rng(0)
    for x in [np.zeros(space.dim), np.ones(space.dim)] + list(rng.uniform(0, 1, (20, space.dim))):
        decoded = space.decode(x)
        for o, start in zip(decoded.objects, scene.objects):
            assert o.position[2] >= floor_height(start) - 1e-9, (o.position, floor_height(start))
            assert o.position[2] >= floor_height(o) - 1e-12, (o.position, floor_height(o))
            assert o.material.sliding_friction >= 0.0 and o.mass > 0
        assert [o.shape for o in decoded.objects] == [o.shape for o in scene.objects]
    # known answer: the box starts on the floor, so the lowest corner keeps it there (not below)
    assert space.decode(np.zeros(space.dim)).objects[0].position[2] == pytest.approx(floor_height(scene.objects[0]))


def test_yaw_rotates_about_world_z():
    scene = _scene()
    space = SearchSpace(scene, ["yaw"], SearchConfig().ranges)   # +-45 deg
    turned = space.decode(np.ones(space.dim))
    q = np.asarray(turned.objects[0].orientation)
    np.testing.assert_allclose(q, [math.cos(math.radians(22.5)), 0, 0, math.sin(math.radians(22.5))], atol=1e-9)


def test_floor_height():
    box = _scene().objects[0]                                  # height 0.15, upright
    assert floor_height(box) == pytest.approx(0.075)
    tilted = _edit(_scene(), 2, orientation=[math.cos(math.pi / 4), math.sin(math.pi / 4), 0, 0]).objects[2]
    assert floor_height(tilted) == pytest.approx(0.08)         # cylinder on its side: radius


# ------------------------------------------------------------------------------ baseline
def test_baseline_scene_most_common_composition_and_slot_means():
    s = _scene()
    two_a = s.replace(objects=[s.objects[1].model_dump(), s.objects[0].model_dump()])      # sphere, box
    moved = _edit(_edit(s, 0, position=[0.0, 0.0, 0.075]), 1, mass=0.5)
    two_b = moved.replace(objects=[moved.objects[0].model_dump(), moved.objects[1].model_dump()])  # box, sphere
    rows = [{"scene_id": "a", "split": "train", "scene": two_a.to_yaml()},
            {"scene_id": "b", "split": "train", "scene": two_b.to_yaml()},
            {"scene_id": "c", "split": "train", "scene": s.to_yaml()},
            {"scene_id": "d", "split": "test", "scene": s.to_yaml()},
            {"scene_id": "e", "split": "test", "scene": s.to_yaml()}]
    base = baseline_scene(rows)
    assert base.composition == ("box", "sphere")
    box, sphere = base.objects                                   # slots in shape order
    assert box.shape == "box" and sphere.shape == "sphere"
    np.testing.assert_allclose(box.position, [-0.1, -0.4, 0.075])
    assert sphere.mass == pytest.approx(0.4)
    with pytest.raises(ValueError, match="no scene"):
        baseline_scene(rows, split="val")


# ------------------------------------------------------------------------------ stages
def _load_stage(name: str):
    """``stages/<name>.py`` as a module (the stages are scripts, not a package)."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "stages" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"stage_{name}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _run_stage(name: str, **constants) -> None:
    """Run ``stages/<name>.py``'s main, with module ``constants`` set first."""
    module = _load_stage(name)
    for key, value in constants.items():
        setattr(module, key, value)
    module.main()


def test_stages_best_of_k_cmaes_score(tmp_path, monkeypatch):
    """The three stages on a tiny dataset: 3 train scenes, 2 test scenes, K = 2 samples (the
    truth and an unparseable output); observed flow = the exact flow."""
    import json

    import pyarrow as pa
    import yaml

    from pipeline import shards

    paths = {k: str(tmp_path / k) for k in ("configs", "video", "flow", "predictions", "best_of_k", "cmaes", "reports")}
    params = {"seed": 0, "paths": paths, "sim": {"timestep": 0.002}, "flow": {"method": "gt"},
              "model": {"input": "flow"}, "search": {"k": 2, "popsize": 2, "iterations": 1}}
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params))
    monkeypatch.setenv("DYNAMICS_PARAMS", str(tmp_path / "params.yaml"))
    base = _scene(duration=0.2)
    scenes = [base, _edit(base, 0, position=[-0.1, -0.8, 0.075]), base.replace(objects=[base.objects[1].model_dump()]),
              _edit(base, 1, position=[0.1, -0.7, 0.3]), base.replace(objects=[base.objects[2].model_dump()])]
    splits = ["train", "train", "train", "test", "test_comp"]
    ids = [shards.scene_id(i) for i in range(len(scenes))]
    shards.write_table(shards.shard_path(paths["configs"], 0, "parquet"),
                       [{"scene_id": i, "split": s, "scene": sc.to_yaml(), "composition": ",".join(sc.composition)}
                        for i, s, sc in zip(ids, splits, scenes)])
    segs, flows = zip(*(evaluate_scene(sc, W, H) for sc in scenes))
    shards.write_arrays(shards.shard_path(paths["video"], 0, "zarr"), {"seg": np.stack(segs)}, {"fps": 30}, ids)
    shards.write_arrays(shards.shard_path(paths["flow"], 0, "zarr"), {"flow": np.stack(flows).astype(np.float16)},
                        scene_ids=ids)
    schema = pa.schema([("scene_id", pa.string()), ("split", pa.string()), ("sample", pa.int32()),
                        ("text", pa.string()), ("scene", pa.string()), ("error", pa.string())])
    preds = [{"scene_id": ids[i], "split": splits[i], "sample": j, "text": "",
              "scene": scenes[i].to_yaml() if j == 1 else None, "error": "no answer" if j == 0 else None}
             for i in (3, 4) for j in (0, 1)]
    shards.write_table(shards.shard_path(paths["predictions"], 0, "parquet"), preds, schema=schema)
    for key in ("configs", "video", "flow", "predictions"):  # finished stages leave a meta.json
        shards.write_meta(paths[key], {"shards": {"shard": 1}})

    for stage in ("best_of_k", "cmaes", "score"):
        _run_stage(stage)

    bok = shards.read_table(paths["best_of_k"]).to_pylist()
    assert [(r["sample"], r["valid"], r["is_best"]) for r in bok] == [(0, False, False), (1, True, True)] * 2
    assert all(r["full_iou"] == 1.0 for r in bok if r["valid"]) and bok[0]["error"] == "no answer"
    rows = shards.read_table(paths["cmaes"]).to_pylist()
    cm = [r for r in rows if r["start"] == "model"]
    assert [r["evaluations"] for r in cm] == [3, 3] and all(r["full_iou"] > 0.99 for r in cm)
    assert [r["start"] for r in rows].count("baseline") == 2  # the trivial baseline is refined too
    assert Scene.from_yaml(cm[0]["scene"]).composition == scenes[3].composition
    metrics = json.loads((tmp_path / "reports" / "metrics.json").read_text())
    test = metrics["methods"]["best_of_k_cmaes"]["test"]
    assert test["n"] == 1 and test["composition_accuracy"] == 1.0 and test["full_iou"] > 0.99
    assert metrics["methods"]["first_sample"]["test_comp"]["full_iou"] == 0.0   # sample 0 did not parse
    table = (tmp_path / "reports" / "table.md").read_text()
    assert "Trivial baseline" in table and "Trivial baseline + CMA-ES" in table
    # the table shows the numbers of metrics.json: every method, split and column, in place
    labels = {"trivial_baseline": "Trivial baseline", "trivial_baseline_cmaes": "Trivial baseline + CMA-ES",
              "first_sample": "Model (first sample)", "best_of_k": "Best@2", "best_of_k_cmaes": "Best@2 + CMA-ES"}
    columns = ["composition_accuracy", "initial_iou", "strict_full_iou", "full_iou", "foreground_iou", "epe"]
    checked = 0
    for section in table.split("### Split `")[1:]:
        split = section.split("`")[0]
        for line in section.splitlines():
            cells = [c.strip() for c in line.strip("|").split("|")]
            method = next((m for m, lab in labels.items() if cells[0] == lab), None)
            if method is None:
                continue
            want = metrics["methods"][method][split]
            for col, cell in zip(columns, cells[2:8]):
                if want[col] is None:
                    assert cell == "–", (method, split, col, cell)
                else:
                    value, _, interval = cell.partition(" [")
                    assert float(value) == pytest.approx(want[col], abs=5e-3 if col == "epe" else 5e-4), (method, split, col)
                    if col in want["ci95"]:   # one scene per split: the interval is the value itself
                        lo, hi = (float(v) for v in interval.rstrip("]").split(","))
                        assert lo == hi == pytest.approx(want[col], abs=5e-3), (method, split, col, cell)
                checked += 1
    assert checked == len(labels) * 2 * len(columns)              # 5 methods x 2 splits
    # paired gain over the first sample: in test_comp sample 0 did not parse (IoU 0), Best@2 is exact
    gain = metrics["strict_iou_gain_over_first_sample"]["best_of_k"]["test_comp"]
    assert gain["n"] == 1 and gain["mean"] == pytest.approx(1.0, abs=1e-3)
    assert "Best@2 +1.000 [+1.000, +1.000]" in table
    # Best@1 beside Best@2 (as Best@4 beside Best@32): the first sample alone, which did not parse
    _run_stage("score", BEST_OF_PREFIXES=(1,))
    metrics = json.loads((tmp_path / "reports" / "metrics.json").read_text())
    assert metrics["methods"]["best_of_1"]["test"]["full_iou"] == 0.0
    assert metrics["methods"]["best_of_1"]["test"]["n_valid"] == 0
    assert metrics["methods"]["best_of_k"]["test"]["full_iou"] == 1.0
    assert re.search(r"^\| Best@1 +\|", (tmp_path / "reports" / "table.md").read_text(), re.M)
    # the progress plot is a drawn figure: decodable, two panels wide, the IoU curve in tab:green
    import cv2

    png = cv2.imread(str(tmp_path / "reports" / "search.png"))
    assert png is not None and png.shape[1] > 1.5 * png.shape[0]
    green = np.abs(cv2.cvtColor(png, cv2.COLOR_BGR2RGB).astype(int) - (44, 160, 44)).sum(-1) < 30
    assert green[:, png.shape[1] // 2:].sum() > 50 and green[:, : png.shape[1] // 2].sum() == 0


def test_best_index_is_the_first_highest_fitness_and_none_without_a_valid_sample():
    from pipeline.search import best_index

    inf = float("inf")
    assert best_index([0.2, 0.7, 0.7, -inf]) == 1          # first on ties
    assert best_index([-inf, -inf]) is None and best_index([]) is None
    assert best_index([-inf, -0.3]) == 1                    # a valid sample with a negative fitness


def test_score_picks_best_of_4_among_the_first_4_of_the_same_samples():
    """Best@4 beside Best@K comes from the first 4 of the K samples the best_of_k stage scored
    (i.i.d. draws): the highest fitness among samples 0-3, none when none of them is valid."""
    score = _load_stage("score")
    inf = float("-inf")
    fits = {"a": [0.1, 0.5, 0.3, 0.2, 0.9, 0.0, 0.0, 0.0],     # Best@8 picks 4, Best@4 picks 1
            "b": [inf, inf, inf, inf, 0.4, 0.1, 0.0, 0.0],     # no valid sample among the first 4
            "c": [0.3, 0.3, inf, 0.1, 0.2, 0.2, 0.2, 0.2]}     # tie: the first
    rows = [{"scene_id": sid, "sample": j, "fitness": None if f == inf else f}
            for sid, fs in fits.items() for j, f in enumerate(fs)]
    picks = score.prefix_picks(rows, k=8)
    assert picks == {4: {"a": 1, "c": 0}}                       # 8 and 16 are not below K = 8
    assert score.prefix_picks(rows, k=4) == {}                  # the default K = 4: no extra row
    assert set(score.prefix_picks(rows, k=32)) == {4, 8, 16}
    assert score.prefix_picks(rows, k=32)[8] == {"a": 4, "b": 4, "c": 0}


def test_parallel_evaluator_equals_the_evaluator():
    """Two worker processes give the clips of one in-process evaluator, in order."""
    from pipeline.search import ParallelEvaluator

    base = _scene()
    cands = [base, *_candidates(base).values()]
    with SceneEvaluator(base, W, H) as ev:
        ref = [ev.evaluate(c, 6) for c in cands]
    for workers in (1, 2):
        with ParallelEvaluator(W, H, workers=workers) as pe:
            out = pe.evaluate_many(cands, 6)
        assert len(out) == len(ref)
        for (s0, f0), (s1, f1) in zip(ref, out):
            np.testing.assert_array_equal(s0, s1)
            np.testing.assert_array_equal(f0, f1)


def test_evaluator_with_static_geometry():
    """Static geometry (``Scene.static``: world geoms ``static_<i>``, not bodies) is part of the
    structure; the evaluator finds the objects' bodies and equals rebuilding the model."""
    from pipeline.scene import Scene as _Scene
    from pipeline.search import structure_key

    if "static" not in _Scene.model_fields:
        pytest.skip("Scene.static not available")
    wall = {"shape": "box", "size": {"width": 0.6, "depth": 0.08, "height": 0.12}, "position": [0.0, -0.55, 0.06]}
    base = _scene(static=[wall])
    moved = _scene(static=[{**wall, "position": [0.1, -0.55, 0.06]}])
    assert structure_key(base) != structure_key(moved) != structure_key(_scene())
    cand = _edit(base, 0, position=[-0.25, -0.85, 0.1], linear_velocity=[0.3, 0.9, 0.0])
    with SceneEvaluator(base, W, H) as ev:
        assert list(ev.bodies) == [1, 2, 3]
        seg, flow = ev.evaluate(cand)
        for stat in ("meanmass", "meaninertia", "meansize", "extent", "center"):
            np.testing.assert_allclose(getattr(ev.model.stat, stat), getattr(compile_model(cand).stat, stat),
                                       rtol=1e-9, err_msg=stat)
        with pytest.raises(ValueError, match="structure"):
            ev.evaluate(moved)
    _, frames = render_scene(cand, W, H, rgb=False, depth=False)
    np.testing.assert_array_equal(seg, frames.seg)
    np.testing.assert_allclose(flow, frames.flow, atol=1e-4)


# ---------------------------------------------------------------------- parallel fitness
@pytest.fixture(scope="module")
def parallel_fitness():
    """An observation of :func:`_scene` with flow and a 2-worker ParallelFitness on it."""
    from pipeline.search.parallel_eval import ParallelFitness

    obs_seg, obs_flow = evaluate_scene(_scene(), W, H)
    with ParallelFitness(obs_seg, obs_flow, SearchConfig(), workers=2) as pf:
        yield obs_seg, obs_flow, pf


def _same_scores(a: list[dict], b: list[dict]) -> bool:
    """Equal fitness dicts, float for float (NaN equal to NaN)."""
    return len(a) == len(b) and all(
        x.keys() == y.keys() and all(x[k] == y[k] or (math.isnan(x[k]) and math.isnan(y[k])) for k in x)
        for x, y in zip(a, b))


def test_parallel_fitness_equals_in_process_fitness(parallel_fitness):
    """Workers score from the observation they got once: the same floats as scoring here."""
    from pipeline.search.parallel_eval import ParallelFitness

    obs_seg, obs_flow, pf = parallel_fitness
    base = _scene()
    cands = [base, *_candidates(base).values()]
    priors = [0.1 * i for i in range(len(cands))]
    for cfg, flow in ((SearchConfig(prior_weight=2.0), obs_flow), (SearchConfig(lambda_epe=0.0), None)):
        with SceneEvaluator(base, W, H) as ev:
            ref = [fitness(*ev.evaluate(c, len(obs_seg), flow=flow is not None), obs_seg, flow, cfg, prior=p)
                   for c, p in zip(cands, priors)]
        if flow is not None:
            out = pf.score(cands, cfg, priors)
            assert all(math.isfinite(r["epe"]) for r in out)
        else:
            with ParallelFitness(obs_seg, None, cfg, workers=1) as local:
                out = local(cands, cfg, priors)
            assert _same_scores(pf.score(cands, cfg, priors), ref)  # lambda 0: no flow rendered
        assert _same_scores(out, ref)
    assert pf.score([]) == []


def test_cmaes_with_parallel_scorer_equals_in_process(parallel_fitness):
    obs_seg, obs_flow, pf = parallel_fitness
    start = _edit(_scene(), 1, position=[0.25, -0.7, 0.3])
    cfg = SearchConfig(popsize=4, iterations=2)
    a, ha = cmaes_refine(start, obs_seg, obs_flow, cfg, seed=5)
    b, hb = cmaes_refine(start, obs_seg, obs_flow, cfg, seed=5, scorer=pf)
    assert a == b
    drop = ("seconds",)
    assert [{k: v for k, v in h.items() if k not in drop} for h in ha] == \
           [{k: v for k, v in h.items() if k not in drop} for h in hb]


def test_evaluator_follows_friction_across_zero():
    """A frictionless object compiles with condim 1 (pipeline.mjcf); an in-place edit that gives
    it friction (or takes it away) must change the contact dimension too, or a spinning puck
    slides in the search and rolls in the re-simulation (found on real clip 02)."""
    base = Scene.from_dict({"camera": {"height": 0.6, "pitch": 60.0}, "objects": [
        {"shape": "cylinder", "size": {"radius": 0.05, "height": 0.02}, "mass": 0.1,
         "position": [0.0, -1.5, 0.01], "linear_velocity": [0.5, 0.0, 0.0],
         "angular_velocity": [-5.0, -3.0, -1.0], "material": {"sliding_friction": 0.0}}]})
    rough = _edit(base, 0, material={"sliding_friction": 0.3, "rolling_friction": 0.0, "damping": 0.0})
    for start, cand in [(base, rough), (rough, base)]:
        with SceneEvaluator(start, W, H) as ev:
            seg, _ = ev.evaluate(cand, flow=False)
        _, frames = render_scene(cand, W, H, rgb=False, depth=False, flow=False)
        np.testing.assert_array_equal(seg, frames.seg)
