"""Direct preference optimisation (DPO) of the scene writer (issue 37): the loss, the sequence
log-probabilities it needs, the chosen/rejected pairs and one optimisation pass.

DPO (Rafailov et al., "Direct Preference Optimization: Your Language Model is Secretly a Reward
Model", NeurIPS 2023, eq. 7) fits a policy ``pi_theta`` to preferences ``y_w > y_l`` for the same
input ``x`` against a frozen reference ``pi_ref``::

    L = -log sigmoid( beta * [ (log pi_theta(y_w|x) - log pi_ref(y_w|x))
                              - (log pi_theta(y_l|x) - log pi_ref(y_l|x)) ] )

``beta * (log pi_theta(y|x) - log pi_ref(y|x))`` is the implicit reward of ``y`` (§5 of the
paper); the *reward margin* is the chosen minus the rejected one. Here ``x`` is the model input of
a video (:func:`pipeline.model.vision.model_input`) and ``y`` a sampled completion
(``<think> ... </think> <answer> ... </answer>``); which of two samples is better is decided by
re-simulating both and scoring them against the video (:mod:`pipeline.adapt`), never by a label.

``trl``'s ``DPOTrainer`` was considered (issue 37 item 3): it drives text or image-text models
through a processor and a chat template, while this model takes the video as Qwen2-VL patches
built by :func:`pipeline.model.batch.collate` and decodes under a scene grammar, so the loss is
written here (eight lines) and tested against a hand-computed value.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F

from pipeline.model.batch import IGNORE_INDEX, collate, encode_target, to_device
from pipeline.model.config import ModelConfig, ModelError


def dpo_loss(policy_chosen: torch.Tensor, policy_rejected: torch.Tensor, ref_chosen: torch.Tensor,
             ref_rejected: torch.Tensor, beta: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The DPO loss of a batch of pairs (Rafailov et al. 2023, eq. 7; see the module docstring).

    Args:
        policy_chosen, policy_rejected: ``(B,)`` float summed log-probabilities (nats) of the
            chosen / rejected completions under the policy.
        ref_chosen, ref_rejected: the same under the frozen reference.
        beta: strength of the KL constraint to the reference (the paper's beta > 0).
    Returns:
        ``(loss, chosen_rewards, rejected_rewards)``: the mean loss (scalar) and the ``(B,)``
        implicit rewards ``beta * (log pi - log pi_ref)``, detached.
    Raises:
        ValueError: ``beta <= 0``.
    """
    if not beta > 0:
        raise ValueError(f"beta: must be > 0, got {beta}")
    chosen = policy_chosen - ref_chosen
    rejected = policy_rejected - ref_rejected
    loss = -F.logsigmoid(beta * (chosen - rejected)).mean()
    return loss, (beta * chosen).detach(), (beta * rejected).detach()


def sequence_logps(model, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """Summed log-probability of each example's target tokens given its prompt (the video).

    Args:
        model: a Qwen2.5-VL of :mod:`pipeline.model.network`.
        batch: :func:`pipeline.model.batch.collate` with targets (``labels (B, L)``, -100 on the
            prompt and padding).
    Returns:
        ``(B,)`` float32 sums over the target positions of ``log p(token_t | tokens_<t, video)``
        (nats), from the model's full-vocabulary softmax at temperature 1 (no grammar mask).
    """
    labels = batch["labels"]
    inputs = {k: v for k, v in batch.items() if k != "labels"}
    logits = model(**inputs, use_cache=False).logits.float()[:, :-1]
    target = labels[:, 1:]
    mask = target != IGNORE_INDEX
    logp = torch.log_softmax(logits, dim=-1).gather(-1, target.clamp(min=0).unsqueeze(-1)).squeeze(-1)
    return (logp * mask).sum(-1)


@dataclass(frozen=True)
class PreferencePair:
    """Two completions for one video, the first re-simulated better than the second.

    Attributes:
        video: index of the video (its model input in the caller's list).
        chosen, rejected: completion texts (space-joined tokens of
            :func:`pipeline.model.sampling.generate`).
        chosen_fitness, rejected_fitness: their search fitness (strict IoU - lambda * EPE).
    """

    video: int
    chosen: str
    rejected: str
    chosen_fitness: float
    rejected_fitness: float


def make_pairs(video: int, texts: Sequence[str | None], fitness: Sequence[float | None], margin: float,
               mode: str = "best_worst") -> list[PreferencePair]:
    """Chosen/rejected pairs of one video's K samples, ranked by their re-simulation's fitness.

    Args:
        video: the video's index; texts: ``(K,)`` completion texts (None: not a valid scene);
        fitness: ``(K,)`` search fitness of each (None: could not be simulated). An invalid sample
            ranks below every valid one (fitness -inf): writing a valid scene is preferred.
        margin: least fitness difference of a pair (smaller ones are noise of the renderer and
            the pseudo masks, not a preference).
        mode: ``best_worst`` (one pair: the best against the worst) or ``all`` (every pair whose
            fitness differs by ``margin``, the better one chosen).
    Returns:
        the pairs (possibly none: all samples equal within ``margin``, or identical texts).
    Raises:
        ValueError: unknown ``mode`` or texts and fitness of different lengths.
    """
    if mode not in ("best_worst", "all"):
        raise ValueError(f"mode: must be best_worst or all, got {mode!r}")
    if len(texts) != len(fitness):
        raise ValueError(f"texts and fitness: must have the same length, got {len(texts)} and {len(fitness)}")
    items = [(t, -np.inf if f is None or not np.isfinite(f) else float(f)) for t, f in zip(texts, fitness)
             if t is not None]
    order = sorted(range(len(items)), key=lambda i: -items[i][1])
    if mode == "best_worst":
        cand = [(order[0], order[-1])] if len(order) >= 2 else []
    else:
        cand = [(a, b) for n, a in enumerate(order) for b in order[n + 1:]]
    pairs = []
    for a, b in cand:
        (ta, fa), (tb, fb) = items[a], items[b]
        if ta != tb and (fa - fb >= margin or (np.isfinite(fa) and not np.isfinite(fb))):
            pairs.append(PreferencePair(video, ta, tb, fa, fb))
    return pairs


def pair_logps(model, inputs: Sequence[np.ndarray], pairs: Sequence[PreferencePair], tokenizer,
               cfg: ModelConfig, grad: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """``(B,)`` summed log-probabilities of the chosen and the rejected completions of ``pairs``
    (:func:`sequence_logps`), one forward pass over the ``2B`` sequences.

    Args:
        inputs: model inputs per video (``pairs[i].video`` indexes it).
        grad: keep the graph (the policy) or not (the reference).
    Raises:
        ModelError: a completion holds a word the tokenizer does not know.
    """
    items = [(inputs[p.video], p.chosen) for p in pairs] + [(inputs[p.video], p.rejected) for p in pairs]
    batch = to_device(collate(items, tokenizer, cfg), next(model.parameters()).device)
    with torch.set_grad_enabled(grad):
        lp = sequence_logps(model, batch)
    return lp[: len(pairs)], lp[len(pairs):]


def encodable(tokenizer, text: str) -> bool:
    """Whether a completion re-encodes to known words (a sample always does; a guard for texts
    read back from a resumed run)."""
    try:
        encode_target(tokenizer, text)
        return True
    except ModelError:
        return False


def dpo_epochs(policy, reference, inputs: Sequence[np.ndarray], pairs: Sequence[PreferencePair], tokenizer,
               cfg: ModelConfig, beta: float, lr: float, epochs: int, batch_pairs: int, seed: int,
               optimizer: torch.optim.Optimizer | None = None, progress=None) -> dict[str, float]:
    """Optimise ``policy`` on ``pairs`` with the DPO loss against ``reference`` (frozen).

    The reference's log-probabilities are computed once; then ``epochs`` passes over the pairs
    in a seeded order, ``batch_pairs`` pairs per AdamW step, gradients clipped to
    ``cfg.grad_clip``.

    Args:
        policy: the model being adapted (trained in place); reference: the frozen start model.
        inputs: model inputs per video; pairs: :func:`make_pairs`' output.
        beta, lr, epochs, batch_pairs, seed: DPO strength, AdamW learning rate, passes, pairs per
            step, order seed.
        optimizer: an AdamW over ``policy``'s parameters to continue (None: a new one).
        progress: a tqdm bar to advance per step, or None.
    Returns:
        ``{loss, reward_margin, reward_accuracy, chosen_reward, rejected_reward, steps}``: means
        over the last epoch (the margin and the accuracy, the fraction of pairs whose chosen
        completion has the higher implicit reward, as ``trl`` logs them).
    """
    if not pairs:
        return {"loss": float("nan"), "reward_margin": float("nan"), "reward_accuracy": float("nan"),
                "chosen_reward": float("nan"), "rejected_reward": float("nan"), "steps": 0}
    reference.eval()
    refs = [pair_logps(reference, inputs, pairs[i: i + batch_pairs], tokenizer, cfg, grad=False)
            for i in range(0, len(pairs), batch_pairs)]
    ref_c = torch.cat([r[0] for r in refs]).detach()
    ref_r = torch.cat([r[1] for r in refs]).detach()
    opt = optimizer or torch.optim.AdamW(policy.parameters(), lr=lr, weight_decay=0.0)
    for g in opt.param_groups:
        g["lr"] = lr
    rng = np.random.default_rng(seed)
    policy.train()
    steps = 0
    last: dict[str, list[float]] = {}
    for _ in range(epochs):
        last = {"loss": [], "margin": [], "acc": [], "chosen": [], "rejected": []}
        order = rng.permutation(len(pairs))
        for i in range(0, len(order), batch_pairs):
            idx = order[i: i + batch_pairs]
            pc, pr = pair_logps(policy, inputs, [pairs[j] for j in idx], tokenizer, cfg, grad=True)
            t = torch.as_tensor(idx)
            loss, rc, rr = dpo_loss(pc, pr, ref_c[t], ref_r[t], beta)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            if cfg.grad_clip > 0:
                torch.nn.utils.clip_grad_norm_(policy.parameters(), cfg.grad_clip)
            opt.step()
            steps += 1
            n = len(idx)
            last["loss"].append(float(loss.detach()) * n)
            last["margin"] += (rc - rr).tolist()
            last["acc"] += (rc > rr).float().tolist()
            last["chosen"] += rc.tolist()
            last["rejected"] += rr.tolist()
            if progress is not None:
                progress.update(1)
    policy.eval()
    return {"loss": sum(last["loss"]) / len(pairs), "reward_margin": float(np.mean(last["margin"])),
            "reward_accuracy": float(np.mean(last["acc"])), "chosen_reward": float(np.mean(last["chosen"])),
            "rejected_reward": float(np.mean(last["rejected"])), "steps": steps}


@torch.no_grad()
def kl_to_reference(policy, reference, inputs: Sequence[np.ndarray], texts: Sequence[tuple[int, str]], tokenizer,
                    cfg: ModelConfig, batch: int = 8) -> float:
    """KL divergence of the policy from the reference along sampled completions, nats per
    completion: ``mean_y sum_t KL(pi_theta(.|x, y_<t) || pi_ref(.|x, y_<t))``, the exact
    per-token KL over the vocabulary summed over each completion's positions (always >= 0; the
    sequence-level KL when ``y ~ pi_theta``). The completions are the round's samples, drawn before
    the update.

    Args:
        texts: ``[(video index, completion text), ...]``.
    Returns:
        the mean over completions (0.0 with no texts).
    """
    if not texts:
        return 0.0
    kls = []
    for i in range(0, len(texts), batch):
        chunk = texts[i: i + batch]
        b = collate([(inputs[v], t) for v, t in chunk], tokenizer, cfg)
        inputs_ = {k: v for k, v in b.items() if k != "labels"}
        mask = (b["labels"][:, 1:] != IGNORE_INDEX).float()
        lp = torch.log_softmax(policy(**inputs_, use_cache=False).logits.float()[:, :-1], -1)
        lq = torch.log_softmax(reference(**inputs_, use_cache=False).logits.float()[:, :-1], -1)
        kl_t = (lp.exp() * (lp - lq)).sum(-1)
        kls.append((kl_t * mask).sum(-1))
    return float(torch.cat(kls).mean())


__all__ = ["dpo_loss", "sequence_logps", "PreferencePair", "make_pairs", "pair_logps", "dpo_epochs",
           "kl_to_reference", "encodable"]
