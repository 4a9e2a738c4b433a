"""Train RAFT here on the CPU: this project's ground-truth flow plus procedural chairs-style pairs.

Data (shares per batch: ``--chairs-fraction``, ``--still-fraction``, the rest rendered):

- the render stage's clips of split ``train`` (``paths.video``: rgb and the simulator's exact
  flow), frames upscaled by :func:`pipeline.raft.estimator.working_scale` exactly as at test time;
- :func:`pipeline.raft.pairs.chairs_pair` pairs at the same size, so the network sees textures,
  motions and edges MuJoCo does not render;
- :func:`pipeline.raft.pairs.still_camera_pair` pairs: a still background and small objects of
  3 px and up moving over it, some smeared, as a fixed camera films a ball or a puck.

Both get the same photometric augmentation (gain, bias, per-channel colour, noise, blur) and
horizontal flips. Loss: the release's sequence loss, ``sum_i gamma^(N-i) |f_i - f_gt|_1`` with
``gamma = 0.8`` (Teed & Deng 2020, eq. 7), plus the same term over moving pixels only, so that
objects of a few percent of the frame count as much as the static floor. AdamW, gradient clipping
at 1 and the release's one-cycle shape (5 % linear warm-up, then linear decay to 0), run on
*progress* = the larger of steps done / ``--steps`` and minutes spent / ``--max-minutes``: on a
shared machine the time limit may come first, and the run still ends annealed.

Resumable: every ``--checkpoint-every`` steps the network, optimiser, schedule, step and random
states go to ``OUT.ckpt``; ``--resume`` continues from it. The final weights are written to
``OUT`` (release layout, :func:`pipeline.raft.estimator.save_raft`) with ``OUT.json`` (steps,
minutes, loss, validation EPE).

    python -m pipeline.raft train --video data/video --configs data/configs \\
        --out pipeline/weights/raft-small-dynamics.pth --steps 4000 --max-minutes 60

On a machine with a GPU and many cores: ``--device cuda --workers 14`` makes the batches in
worker processes (each with its own random stream, seeded from ``--seed``, the worker and the
step it started at, so a resumed run is reproducible only with ``--workers 0``).
``python -m pipeline.raft export`` packs the render shards into one ``.npz`` for ``--data``, so
such a machine needs neither the shards nor zarr (it needs numpy, OpenCV, torch, pyarrow and
pydantic: carry wheels of the last two to a GPU box that lacks them); ``--textures BANK.npz`` (``python -m
pipeline.raft textures VIDEO...``) cuts half the chairs layers from real frames.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from pipeline import shards
from pipeline.raft.estimator import RaftFlow, save_raft, working_scale
from pipeline.raft.model import RAFT, RaftArch
from pipeline.raft.pairs import chairs_pair, still_camera_pair

GAMMA = 0.8
"""Weight decay of earlier iterates in the sequence loss (release value)."""


def load_split(video_dir: str | Path, configs_dir: str | Path, split: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Clips of one split from the render stage's shards.

    Returns:
        ``rgb (N, T, H, W, 3) uint8``, ``flow (N, T-1, H, W, 2) float16`` px (ground truth) and
        ``seg (N, T, H, W) int8`` (object index, -1 background).

    Raises:
        FileNotFoundError: no shards, or no clip of ``split``.
    """
    table = shards.read_table(configs_dir, columns=["scene_id", "split"])
    want = {s for s, sp in zip(table.column("scene_id").to_pylist(), table.column("split").to_pylist()) if sp == split}
    rgb, flow, seg = [], [], []
    for _, group in shards.iter_array_shards(video_dir):
        ids = shards.scene_ids_of(group)
        idx = [i for i, s in enumerate(ids) if s in want]
        if idx:
            rgb.append(np.asarray(group["rgb"].get_orthogonal_selection((idx,))))
            flow.append(np.asarray(group["flow"].get_orthogonal_selection((idx,))))
            seg.append(np.asarray(group["seg"].get_orthogonal_selection((idx,))))
    if not rgb:
        raise FileNotFoundError(f"{video_dir}: no clip of split {split!r} (run `dvc repro render` first)")
    return np.concatenate(rgb), np.concatenate(flow), np.concatenate(seg)


FLOW_QUANT = 64
"""Steps per px of the flow stored by :func:`export_data` (int16: +-512 px at 1/64 px)."""


def export_data(video_dir: str | Path, configs_dir: str | Path, out: str | Path) -> Path:
    """Pack the ``train`` and ``val`` clips of the render shards into one compressed ``.npz``
    (``train_rgb``, ``train_flow``, ``val_rgb``, ``val_flow``, ``val_seg``; flow stored as int16
    in units of 1/:data:`FLOW_QUANT` px, which compresses three times better than float16) for
    :func:`train`'s ``data``; written via a temp file and rename."""
    out = Path(out)
    arrays = {}
    for split in ("train", "val"):
        rgb, flow, seg = load_split(video_dir, configs_dir, split)
        arrays |= {f"{split}_rgb": rgb, f"{split}_flow": np.round(flow.astype(np.float32) * FLOW_QUANT).astype(np.int16)}
        if split == "val":
            arrays["val_seg"] = seg
    tmp = out.with_name(out.name + ".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    tmp.replace(out)
    return out


def load_data(data: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``train_rgb, train_flow, val_rgb, val_flow, val_seg`` of an :func:`export_data` file
    (dtypes of :func:`load_split`: uint8, float16 px, int8).

    Raises:
        FileNotFoundError: no such file. KeyError: an array missing from it.
    """
    data = Path(data)
    if not data.is_file():
        raise FileNotFoundError(f"{data}: no such file (python -m pipeline.raft export writes it)")
    with np.load(data) as z:
        missing = [k for k in ("train_rgb", "train_flow", "val_rgb", "val_flow", "val_seg") if k not in z]
        if missing:
            raise KeyError(f"{data}: missing array(s) {missing}")
        return (z["train_rgb"], (z["train_flow"] / FLOW_QUANT).astype(np.float16), z["val_rgb"],
                (z["val_flow"] / FLOW_QUANT).astype(np.float16), z["val_seg"])


def _upscale(img1: np.ndarray, img2: np.ndarray, flow: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Images bilinear, flow nearest and times ``s``, as :class:`RaftFlow` sees frames."""
    if s == 1:
        return img1, img2, flow.astype(np.float32)
    H, W = img1.shape[:2]
    size = (round(W * s), round(H * s))
    up = [cv2.resize(i, size, interpolation=cv2.INTER_LINEAR) for i in (img1, img2)]
    return up[0], up[1], cv2.resize(flow.astype(np.float32), size, interpolation=cv2.INTER_NEAREST) * s


def _photometric(rng: np.random.Generator, pair: np.ndarray) -> np.ndarray:
    """The same random gain, bias, colour and blur for both images, noise per image:
    ``(2, H, W, 3)`` uint8 -> float32 in [0, 255]."""
    x = pair.astype(np.float32)
    x = x * rng.uniform(0.6, 1.4) * rng.uniform(0.85, 1.15, 3) + rng.uniform(-30, 30)
    if rng.random() < 0.3:
        sigma = rng.uniform(0.3, 1.2)
        x = np.stack([cv2.GaussianBlur(i, (0, 0), sigma) for i in x])
    x = x + rng.normal(0, rng.uniform(0, 4), x.shape)
    if rng.random() < 0.1:
        x = np.repeat(x.mean(axis=-1, keepdims=True), 3, axis=-1)
    return np.clip(x, 0, 255).astype(np.float32)


def _crop_at_motion(rng: np.random.Generator, a: np.ndarray, b: np.ndarray, f: np.ndarray,
                    crop: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A ``crop = (h, w)`` window of a pair, centred near a random moving pixel 4 times in 5
    (most of a rendered frame is static floor), anywhere otherwise."""
    H, W = a.shape[:2]
    ch, cw = min(crop[0], H), min(crop[1], W)
    moving = np.argwhere(np.abs(f).sum(-1) > 0.05)
    if len(moving) and rng.random() < 0.8:
        cy, cx = moving[rng.integers(len(moving))]
        y0, x0 = int(np.clip(cy - ch // 2 + rng.integers(-ch // 4, ch // 4 + 1), 0, H - ch)), \
            int(np.clip(cx - cw // 2 + rng.integers(-cw // 4, cw // 4 + 1), 0, W - cw))
    else:
        y0, x0 = int(rng.integers(H - ch + 1)), int(rng.integers(W - cw + 1))
    win = (slice(y0, y0 + ch), slice(x0, x0 + cw))
    return a[win], b[win], f[win]


SHIFTS = (4.0, 10.0, 20.0, 32.0)
"""Largest layer translations (px) of chairs pairs, one drawn per pair."""


def make_batch(rng: np.random.Generator, rgb: np.ndarray, flow: np.ndarray, batch: int,
               chairs_fraction: float, crop: tuple[int, int] | None = None,
               textures: np.ndarray | None = None, still_fraction: float = 0.0
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``img1, img2 (B, 3, h, w)`` float [0, 255] and ``flow (B, 2, h, w)`` px at the working size,
    or ``crop = (h, w)`` windows of it (multiples of 8). Each pair is a chairs pair with probability
    ``chairs_fraction``, a still-camera pair (:func:`pipeline.raft.pairs.still_camera_pair`) with
    probability ``still_fraction``, else a rendered pair; ``textures``: see
    :func:`pipeline.raft.pairs.chairs_pair`.

    Raises:
        ValueError: fractions outside [0, 1] or summing to more than 1.
    """
    return _to_tensors(_batch_arrays(rng, rgb, flow, batch, chairs_fraction, crop, textures, still_fraction))


def _batch_arrays(rng: np.random.Generator, rgb: np.ndarray, flow: np.ndarray, batch: int,
                  chairs_fraction: float, crop: tuple[int, int] | None = None,
                  textures: np.ndarray | None = None, still_fraction: float = 0.0
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`make_batch` as ``(B, h, w, C)`` float32 numpy arrays (what DataLoader workers send)."""
    if not (0 <= chairs_fraction <= 1 and 0 <= still_fraction <= 1 and chairs_fraction + still_fraction <= 1):
        raise ValueError(f"chairs_fraction {chairs_fraction} + still_fraction {still_fraction}: "
                         "each must be in [0, 1] and their sum at most 1")
    H, W = rgb.shape[2:4]
    s = working_scale(H, W)
    h, w = round(H * s), round(W * s)
    i1, i2, fl = [], [], []
    for _ in range(batch):
        r = rng.random()
        if r < chairs_fraction:
            a, b, f = chairs_pair(rng, *(crop or (h, w)), max_shift=float(rng.choice(SHIFTS)), textures=textures)
        elif r < chairs_fraction + still_fraction:
            a, b, f = still_camera_pair(rng, *(crop or (h, w)), max_shift=float(rng.choice(SHIFTS[:3])),
                                        textures=textures)
        else:
            n, t = int(rng.integers(len(rgb))), int(rng.integers(flow.shape[1]))
            a, b, f = _upscale(rgb[n, t], rgb[n, t + 1], flow[n, t], s)
            if crop is not None:
                a, b, f = _crop_at_motion(rng, a, b, f, crop)
        pair = _photometric(rng, np.stack([a, b]))
        f = f.copy()
        if rng.random() < 0.5:                     # horizontal flip: u changes sign
            pair, f = pair[:, :, ::-1], f[:, ::-1] * np.array([-1, 1], np.float32)
        i1.append(pair[0]), i2.append(pair[1]), fl.append(f)
    return tuple(np.ascontiguousarray(np.stack(xs), dtype=np.float32) for xs in (i1, i2, fl))


def _to_tensors(arrays) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(B, h, w, C)`` arrays or tensors -> ``(B, C, h, w)`` float32 tensors."""
    return tuple(torch.as_tensor(a).permute(0, 3, 1, 2).float() for a in arrays)


class _Batches(torch.utils.data.IterableDataset):
    """Endless batches (:func:`_batch_arrays`, numpy only) made in DataLoader workers, one random
    stream each (seeded from ``seed``, the step the run starts at and the worker's id)."""

    def __init__(self, seed: int, start_step: int, *args) -> None:
        super().__init__()
        self.seed, self.start_step, self.args = seed, start_step, args

    def __iter__(self):
        info = torch.utils.data.get_worker_info()
        cv2.setNumThreads(1)
        rng = np.random.default_rng([self.seed, self.start_step, info.id if info else 0])
        while True:
            yield _batch_arrays(rng, *self.args)


def learning_rate(peak: float, progress: float, warmup: float = 0.05) -> float:
    """One-cycle learning rate at ``progress`` in [0, 1]: linear warm-up over ``warmup``, then
    linear decay to 0 (the release's OneCycleLR with ``anneal_strategy='linear'``)."""
    progress = min(max(progress, 0.0), 1.0)
    if progress < warmup:
        return peak * max(progress / warmup, 0.01)
    return peak * (1 - progress) / (1 - warmup)


def sequence_loss(preds: list[torch.Tensor], gt: torch.Tensor, gamma: float = GAMMA) -> torch.Tensor:
    """``sum_i gamma^(N-1-i) (mean |f_i - gt|_1 + mean over moving pixels |f_i - gt|_1)``.

    ``preds``: N tensors ``(B, 2, H, W)``; ``gt``: ``(B, 2, H, W)`` px. The first term is the
    release's loss (Teed & Deng 2020, eq. 7); the second averages over pixels whose true flow is
    above 0.05 px (zero when there are none)."""
    moving = (gt.norm(dim=1, keepdim=True) > 0.05).float()
    n_moving = moving.sum().clamp(min=1.0)
    total = gt.new_zeros(())
    for i, p in enumerate(preds):
        err = (p - gt).abs()
        total = total + gamma ** (len(preds) - 1 - i) * (err.mean() + (err * moving).sum() / (2 * n_moving))
    return total


def epe(flow: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean end-point error (px) of ``flow`` against ``gt`` (``(..., H, W, 2)``) over ``mask``
    (``(..., H, W)`` bool; all pixels when None); NaN when the mask is empty."""
    e = np.linalg.norm(flow.astype(np.float64) - gt.astype(np.float64), axis=-1)
    if mask is not None:
        e = e[mask]
    return float(e.mean()) if e.size else float("nan")


def validate(net: RAFT, rgb: np.ndarray, flow: np.ndarray, seg: np.ndarray, iters: int = 12) -> dict:
    """EPE (px) of ``net`` on clips: all pixels and foreground (object pixels of frame t)."""
    est = RaftFlow(net, iters=iters)
    preds = np.stack([est(clip) for clip in rgb])
    fg = seg[:, :-1] >= 0
    return {"epe_all": epe(preds, flow), "epe_fg": epe(preds, flow, fg)}


def train(video: Path, configs: Path, out: Path, steps: int = 4000, batch: int = 6, iters: int = 8,
          lr: float = 4e-4, chairs_fraction: float = 0.5, max_minutes: float = 60.0, seed: int = 0,
          resume: bool = False, checkpoint_every: int = 100, eval_every: int = 500,
          arch: RaftArch = RaftArch(small=True, convex=True), crop: tuple[int, int] | None = None,
          init: Path | None = None, data: Path | None = None, textures: Path | None = None,
          device: str = "cpu", workers: int = 0, still_fraction: float = 0.0) -> dict:
    """Train and write ``out`` (weights) and ``out.json`` (summary, returned). See module doc.

    ``data``: an :func:`export_data` file used instead of the shards ``video``/``configs``;
    ``textures``: a ``.npz`` with a ``bank`` array (:func:`pipeline.raft.pairs.texture_bank`);
    ``device``: torch device of the network; ``workers``: DataLoader processes making batches
    (0: in this process, the random state checkpointed with the network); ``still_fraction``:
    share of :func:`pipeline.raft.pairs.still_camera_pair` pairs per batch."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    if data is not None:
        rgb, flow, vrgb, vflow, vseg = load_data(data)
    else:
        rgb, flow, _ = load_split(video, configs, "train")
        vrgb, vflow, vseg = load_split(video, configs, "val")
    bank = None
    if textures is not None:
        with np.load(textures) as z:
            bank = z["bank"]
        print(f"texture bank {textures}: {len(bank)} frames", flush=True)
    dev = torch.device(device)
    if dev.type == "cuda":
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
        torch.backends.cudnn.benchmark = True
    net = RAFT(arch)
    if init is not None:   # weights of an earlier run (a .pth or the .ckpt of a run); a new schedule
        state = torch.load(init, map_location="cpu", weights_only=False)
        net.load_state_dict(state["net"] if "net" in state else {k.removeprefix("module."): v for k, v in state.items()})
        print(f"initialised from {init}", flush=True)
    net.to(dev)              # before the optimiser, so its state lives on the same device
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=1e-5, eps=1e-8)
    ckpt, step, spent, history = Path(str(out) + ".ckpt"), 0, 0.0, []
    ckpt.parent.mkdir(parents=True, exist_ok=True)
    if resume and ckpt.is_file():
        state = torch.load(ckpt, map_location="cpu", weights_only=False)
        net.load_state_dict(state["net"]), opt.load_state_dict(state["opt"])
        step, spent, history = state["step"], state["minutes"], state["history"]
        rng.bit_generator.state = state["rng"]
        torch.set_rng_state(state["torch_rng"])
        print(f"resumed at step {step} ({spent:.1f} min)", flush=True)
    batches = None
    if workers > 0:
        batches = iter(torch.utils.data.DataLoader(
            _Batches(seed, step, rgb, flow, batch, chairs_fraction, crop, bank, still_fraction), batch_size=None,
            num_workers=workers, pin_memory=dev.type == "cuda", prefetch_factor=4,
            multiprocessing_context="spawn"))   # a fork can hang on thread pools (OpenMP, EGL) the parent started
    start, losses = time.time(), []

    def save_ckpt() -> None:
        tmp = ckpt.with_name(ckpt.name + ".tmp")
        torch.save({"net": net.state_dict(), "opt": opt.state_dict(), "step": step,
                    "minutes": spent + (time.time() - start) / 60, "history": history,
                    "rng": rng.bit_generator.state, "torch_rng": torch.get_rng_state()}, tmp)
        tmp.replace(ckpt)

    net.train()
    while step < steps and spent + (time.time() - start) / 60 < max_minutes:
        rate = learning_rate(lr, max(step / steps, (spent + (time.time() - start) / 60) / max_minutes))
        for group in opt.param_groups:
            group["lr"] = rate
        i1, i2, gt = _to_tensors(next(batches)) if batches is not None else make_batch(rng, rgb, flow, batch,
                                                                                       chairs_fraction, crop, bank,
                                                                                       still_fraction)
        i1, i2, gt = (x.to(dev, non_blocking=True) for x in (i1, i2, gt))
        loss = sequence_loss(net(i1, i2, iters=iters), gt)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
        opt.step()
        step += 1
        losses.append(loss.item())
        if step % 25 == 0:
            minutes = spent + (time.time() - start) / 60
            print(f"step {step}/{steps} loss {np.mean(losses[-25:]):.3f} lr {rate:.2e} "
                  f"{minutes:.1f} min", flush=True)
        if step % eval_every == 0 or step == steps:
            net.eval()
            v = validate(net, vrgb[:, :9], vflow[:, :8], vseg[:, :9])
            net.train()
            history.append({"step": step, "loss": float(np.mean(losses[-100:])), **v})
            print(f"val step {step}: EPE all {v['epe_all']:.3f} px, foreground {v['epe_fg']:.3f} px", flush=True)
        if step % checkpoint_every == 0:
            save_ckpt()
            save_raft(net, out)      # the latest weights, so a run cut off still leaves a usable file
    save_ckpt()
    net.eval()
    minutes = spent + (time.time() - start) / 60
    v = validate(net, vrgb, vflow, vseg)
    summary = {"steps": step, "minutes": round(minutes, 1), "batch": batch, "train_iters": iters, "lr": lr,
               "chairs_fraction": chairs_fraction, "still_fraction": still_fraction, "crop": list(crop) if crop else None,
               "init": str(init) if init else None, "seed": seed, "device": str(dev), "workers": workers,
               "textures": {"file": str(textures), "frames": int(len(bank))} if bank is not None else None, "arch": {"small": arch.small, "convex": arch.convex},
               "parameters": sum(p.numel() for p in net.parameters()),
               "final_loss": float(np.mean(losses[-100:])) if losses else None,
               "val": v, "history": history,
               "data": {"video": str(data or video), "train_clips": int(len(rgb)), "train_pairs": int(len(rgb) * flow.shape[1])}}
    save_raft(net, out)
    tmp = Path(str(out) + ".json.tmp")
    tmp.write_text(json.dumps(summary, indent=1) + "\n")
    tmp.replace(Path(str(out).removesuffix(".pth") + ".json"))
    print(f"wrote {out}: {step} steps, {minutes:.1f} min, val EPE all {v['epe_all']:.3f} fg {v['epe_fg']:.3f}", flush=True)
    return summary
