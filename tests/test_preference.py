"""Label-free preference optimisation (issue 37): the DPO loss against a hand-computed value,
the sequence log-probabilities against the model's own cross-entropy, the pairs, one DPO pass
moving the policy the right way, and ``dynamics adapt`` on a folder that holds only videos."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import yaml

from pipeline.model import SHIPPED_CHECKPOINT, ModelConfig, checkpoint_config, collate, load_codec, load_model
from pipeline.model.preference import (PreferencePair, dpo_epochs, dpo_loss, kl_to_reference, make_pairs,
                                       sequence_logps)


def test_dpo_loss_equals_the_papers_equation_by_hand():
    """Rafailov et al. 2023, eq. 7 for two pairs, beta 0.5. Pair 1: the policy raised the
    chosen completion by 1 nat over the reference and lowered the rejected one by 1 nat:
    -log sigmoid(0.5 * (1 - (-1))) = log(1 + e^-1) = 0.313262. Pair 2: no change: log 2."""
    pc, pr = torch.tensor([-10.0, -5.0]), torch.tensor([-12.0, -7.0])
    rc, rr = torch.tensor([-11.0, -5.0]), torch.tensor([-11.0, -7.0])
    loss, chosen, rejected = dpo_loss(pc, pr, rc, rr, beta=0.5)
    assert float(loss) == pytest.approx((math.log1p(math.exp(-1.0)) + math.log(2.0)) / 2, abs=1e-6)
    assert chosen.tolist() == pytest.approx([0.5, 0.0]) and rejected.tolist() == pytest.approx([-0.5, 0.0])
    with pytest.raises(ValueError, match="beta"):
        dpo_loss(pc, pr, rc, rr, beta=0.0)


def test_make_pairs_ranks_by_fitness_with_a_margin():
    texts = ["a", "b", "c", "a"]
    fitness = [0.5, 0.1, None, 0.49]     # c could not be simulated: below every valid sample
    pairs = make_pairs(3, texts, fitness, margin=0.05, mode="all")
    got = {(p.chosen, p.rejected) for p in pairs}
    # a > b (0.4 apart), a > c and b > c (c invalid); a vs a (same text) and a 0.5 vs a 0.49 are no pairs
    assert got == {("a", "b"), ("a", "c"), ("b", "c")}
    assert all(p.video == 3 for p in pairs)
    best_worst = make_pairs(0, texts, fitness, margin=0.05, mode="best_worst")
    assert [(p.chosen, p.rejected) for p in best_worst] == [("a", "c")]
    assert make_pairs(0, ["x", "y"], [0.30, 0.29], margin=0.05) == []   # within the margin: no preference
    with pytest.raises(ValueError, match="mode"):
        make_pairs(0, texts, fitness, margin=0.0, mode="top")


@pytest.fixture(scope="module")
def shipped():
    if not (SHIPPED_CHECKPOINT / "config.json").exists():
        pytest.skip("no shipped checkpoint")
    model, tok = load_model(SHIPPED_CHECKPOINT)
    codec, _ = load_codec(SHIPPED_CHECKPOINT)
    params = yaml.safe_load(Path("params.yaml").read_text())
    cfg = checkpoint_config(SHIPPED_CHECKPOINT, ModelConfig.from_params(params))
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 255, (cfg.n_input_frames, 64, 96, 3), dtype=np.uint8)
    return model, tok, codec, cfg, frames


def _completions(model, tok, codec, cfg, frames, k=2):
    from pipeline.model import generate
    hot = cfg.model_copy(update={"temperature": 1.0, "top_p": 1.0})
    outs = [" ".join(t) for t in generate(model, tok, frames, hot, codec, k=k, seed=3)]
    assert len(set(outs)) == k, "need distinct samples"
    return outs


def test_sequence_logps_is_minus_the_models_own_cross_entropy(shipped):
    """The summed log-probability of a completion equals -(HF's mean token cross-entropy) x the
    number of target tokens (the same teacher-forced positions, computed independently)."""
    model, tok, codec, cfg, frames = shipped
    text = _completions(model, tok, codec, cfg, frames, k=2)[0]
    batch = collate([(frames, text)], tok, cfg)
    n = int((batch["labels"][:, 1:] != -100).sum())
    with torch.no_grad():
        ours = float(sequence_logps(model, batch)[0])
        ce = float(model(**batch, use_cache=False).loss)
    assert n == len(text.split()) + 1   # the completion's tokens and EOS
    assert ours == pytest.approx(-ce * n, rel=1e-4)


def test_a_dpo_pass_raises_the_chosen_completion_and_moves_away_from_the_reference(shipped):
    """One pair, a few passes: the implicit reward margin turns positive, the loss falls below
    log 2 (its value at the start, policy = reference), the chosen completion's log-probability
    rises relative to the rejected one's, and the KL to the reference, 0 at the start, grows."""
    import copy

    model, tok, codec, cfg, frames = shipped
    policy = copy.deepcopy(model)
    reference = model
    good, bad = _completions(model, tok, codec, cfg, frames, k=2)
    pairs = [PreferencePair(0, good, bad, 0.8, 0.1)]
    b = collate([(frames, good), (frames, bad)], tok, cfg)
    with torch.no_grad():
        before = sequence_logps(policy, b)
    assert kl_to_reference(policy, reference, [frames], [(0, good), (0, bad)], tok, cfg) == pytest.approx(0.0, abs=1e-6)
    stats = dpo_epochs(policy, reference, [frames], pairs, tok, cfg, beta=0.1, lr=1e-3, epochs=4, batch_pairs=1,
                       seed=0)
    with torch.no_grad():
        after = sequence_logps(policy, b)
    assert stats["steps"] == 4 and stats["reward_accuracy"] == 1.0 and stats["reward_margin"] > 0
    assert stats["loss"] < math.log(2.0)
    assert (after[0] - after[1]) > (before[0] - before[1]) + 1.0
    assert kl_to_reference(policy, reference, [frames], [(0, good), (0, bad)], tok, cfg) > 0.01


def _ball_video(path: Path) -> None:
    from pipeline.render import render_scene
    from pipeline.scene import Scene

    scene = Scene.from_dict({"duration": 1.2, "fps": 30, "camera": {"height": 1.2, "pitch": 35.0, "fov": 45.0},
                             "objects": [{"shape": "sphere", "size": {"radius": 0.1}, "mass": 0.5,
                                          "position": [-0.3, -0.2, 0.1], "linear_velocity": [0.8, 0.1, 0.0]}]})
    _, fr = render_scene(scene, 320, 240)
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30, (320, 240))
    for f in fr.rgb:
        w.write(cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    w.release()


def test_dynamics_adapt_on_a_folder_of_videos_writes_a_checkpoint_infer_loads_and_resumes(tmp_path, shipped):
    """`dynamics adapt FOLDER` where the folder holds only a video (no labels of any kind): one
    round writes a checkpoint that loads like the shipped one (check_checkpoint, samples), with
    different weights, the per-round log (beta, margin, KL, guard), and a second call resumes
    (nothing left to do) instead of starting over."""
    from pipeline import cli
    from pipeline.model import check_checkpoint

    videos = tmp_path / "videos"
    videos.mkdir()
    _ball_video(videos / "ball.mp4")
    assert [p.name for p in videos.iterdir()] == ["ball.mp4"]
    params = yaml.safe_load(Path("params.yaml").read_text())
    params["preference"].update(guard_scenes=2, guard_drop=1.0, margin=0.0, epochs=1, k=3)
    pfile = tmp_path / "params.yaml"
    pfile.write_text(yaml.safe_dump(params))
    out = tmp_path / "adapted"
    argv = ["adapt", str(videos), "--out", str(out), "--model", str(SHIPPED_CHECKPOINT), "--rounds", "1",
            "--params", str(pfile)]
    assert cli.main(argv) == 0
    check_checkpoint(out)
    rows = list(csv.DictReader((out / "adapt_log.csv").open()))
    assert [int(r["round"]) for r in rows] == [0, 1]
    r1 = rows[1]
    assert int(r1["videos"]) == 1 and int(r1["samples"]) == 3 and int(r1["pairs"]) >= 1
    assert float(r1["beta"]) == 0.1 and float(r1["kl"]) > 0 and r1["accepted"] == "True"
    assert (out / "adapt_curve.png").stat().st_size > 0
    base, _ = load_model(SHIPPED_CHECKPOINT)
    new, _ = load_model(out)
    diff = max(float((a - b).detach().abs().max()) for a, b in zip(base.parameters(), new.parameters()))
    assert diff > 0
    mtime = (out / "adapt_state.json").stat().st_mtime
    assert cli.main(argv) == 0 and (out / "adapt_state.json").stat().st_mtime == mtime   # resumed: no new round
    assert cli.main(["adapt", str(tmp_path / "nothing"), "--out", str(out)]) == 2   # one-line error
