"""The hand-written truths about the real clips (issue 29): every clip of scripts/realvideo_all.py is
described once in content.yaml with known values, and physical_truth.yaml names clips and files
that exist; the 19-clip table's content columns score a written scene as described."""

import importlib.util
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
FIX = ROOT / "tests" / "fixtures" / "realvideo"


def _realvideo_all():
    spec = importlib.util.spec_from_file_location("realvideo_all", ROOT / "scripts" / "realvideo_all.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_content_describes_every_clip_once_with_known_values():
    rv = _realvideo_all()
    content = yaml.safe_load((FIX / "content.yaml").read_text())
    assert set(content) == {name for name, _, _ in rv.CLIPS}
    for name, c in content.items():
        assert c["objects"] and set(c["objects"]) <= {"sphere", "cylinder", "box"}, name
        assert c["support"] in {"floor", "incline", "none"} and c["view"] in {"side", "oblique", "top"}, name


def test_physical_truths_name_clips_and_files_that_exist():
    rv = _realvideo_all()
    files = {name: rel for name, rel, _ in rv.CLIPS}
    truth = yaml.safe_load((FIX / "physical_truth.yaml").read_text())
    for name, t in truth.items():
        assert files[name] == t["file"], name
        assert t["fps"] > 0 and ("m_per_px" in t or "incline_deg" in t), name
        if "labels" in t:
            assert (FIX / t["labels"]).is_dir(), name


def test_content_columns_score_a_written_scene(tmp_path):
    rv = _realvideo_all()
    clip = tmp_path / "07_rolling_cylinder"
    clip.mkdir()
    (clip / "metrics.json").write_text('{"view": "side"}')
    ramp = {"shape": "box", "size": {"width": 1.0, "depth": 0.2, "height": 0.02}, "position": [0.0, 0.0, 0.1],
            "orientation": [0.99965, 0.0, 0.026177, 0.0]}                         # 3 deg about y
    scene = {"duration": 1.0, "fps": 30, "camera": {"height": 1.0, "pitch": 10.0, "fov": 45.0},
             "objects": [{"shape": "cylinder", "size": {"radius": 0.05, "height": 0.02}, "mass": 0.1,
                          "position": [0.0, 0.0, 0.3]}], "static": [ramp]}
    (clip / "scene.yaml").write_text(yaml.safe_dump(scene))
    row = rv.content_columns("07_rolling_cylinder", clip)
    assert row["shapes_right"] and row["support_written"] == "incline" and row["support_right"]
    scene["static"] = []
    scene["objects"][0] = {"shape": "sphere", "size": {"radius": 0.05}, "mass": 0.1, "position": [0.0, 0.0, 0.3]}
    (clip / "scene.yaml").write_text(yaml.safe_dump(scene))
    row = rv.content_columns("07_rolling_cylinder", clip)
    assert not row["shapes_right"] and row["support_written"] == "floor" and row["support_right"] is False
    assert row["objects_written"] == row["objects_true"] == 1


def test_shape_choice_says_which_rule_picked_the_shapes():
    """Issue 29 item 4: per clip, the shape chosen and why (the fittest, the silhouettes, the parsimony rule, a
    model sample)."""
    rv = _realvideo_all()
    proposals = [{"source": "model", "label": "model sample 0", "valid": True, "fitness": 0.1},
                 {"source": "perception", "label": "perception: top: cylinder", "valid": True, "fitness": 0.474},
                 {"source": "perception", "label": "perception: top: sphere", "valid": True, "fitness": 0.46},
                 {"source": "perception", "label": "perception: top: box", "valid": False, "fitness": None}]
    m = {"proposals": proposals, "best_of_k_source": "perception", "best_of_k_label": "perception: top: sphere",
         "best_of_k_fittest_label": "perception: top: cylinder"}
    c = rv.shape_choice(m)
    assert c["hypotheses"] == [("top: cylinder", 0.474), ("top: sphere", 0.46)]     # valid perception ones only
    assert c["picked"] == "perception: top: sphere" and c["why"].startswith("parsimony")
    assert rv.shape_choice({**m, "best_of_k_label": "perception: top: cylinder"})["why"] == "fittest"
    assert rv.shape_choice({**m, "best_of_k_source": "model"})["why"] == "a model sample was fittest"
    # the silhouettes favour the pick (a lower silhouette_rank than the fittest's): they decided, not parsimony
    ranked = [{**p, "silhouette_rank": 1 if p["label"].endswith("cylinder") else 0} for p in proposals]
    assert rv.shape_choice({**m, "proposals": ranked, "shape_tiebreak": "silhouette"})["why"].startswith("silhouettes")
    assert rv.shape_choice({**m, "proposals": ranked})["why"].startswith("parsimony")   # the default rule


def test_table_counts_a_failed_clip_as_zero_not_as_missing():
    """A clip the main job fails on (e.g. nothing seen in its window) scores 0 in the table's means
    and is wrong in its counts: leaving it out would be credit by omission."""
    rv = _realvideo_all()
    good = {"clip": "a", "file": "a.mp4", "fps": None, "seconds": 1.0, "best_of_k": 0.5, "best_of_k_strict": 0.5,
            "written": 0.8, "written_strict": 0.8, "window_s": 1.0, "simulate": "ok", "resim_iou": 1.0,
            "objects_written": 1, "objects_true": 1, "shapes_written": ["sphere"], "shapes_true": ["sphere"],
            "shapes_right": True, "support_written": "floor", "support_true": "floor", "support_right": True,
            "view_written": "side", "view_true": "side"}
    failed = {"clip": "b", "file": "b.mp4", "fps": None, "seconds": 1.0, "error": "error: nothing to reconstruct"}
    text = rv.table([good, failed])
    assert "clips run: 1/2" in text and "0.4000 (strict, no free credit: 0.4000)" in text
    assert "object count right 1/2, shapes right 1/2" in text and "strict IoU >= 0.5: 1/2" in text
