"""A small class-agnostic object segmenter: which pixels belong to *some* rigid object, moving or
still, and where two objects touch (issue 36).

Background subtraction sees only what moves: an object at rest throughout the clip is in the
background model, a slow one comes out as a crescent. This network looks at one frame *and* at its
difference from the clip's median background, so motion is a cue but not the only one. It is
trained here, on the CPU, on randomised MuJoCo renders (``pipeline.truthsets``: floor textures,
colours, light and camera pitch 0-90 deg randomised) with the renderer's true instance masks.

Network: a U-Net (Ronneberger et al., MICCAI 2015) of four levels, 12-24-32-48 channels, batch
norm and ReLU, bilinear upsampling; 0.12 M parameters. Fully convolutional: any image size whose
sides are multiples of 8 (inputs are padded).

Input ``(4, H, W)`` float32: RGB / 255 - 0.5, and the largest RGB difference from the median
background / 255 (``pipeline.masks`` conventions). Output ``(2, H, W)`` logits: foreground (the
pixel belongs to an object) and *contact* (the pixel lies within a few px of a boundary between two
different objects, :data:`CONTACT_PX`), the cue that splits touching objects.

Usage::

    python -m pipeline.segmenter train --data data/truthsets/mujoco/train --out pipeline/weights/segmenter.pt
    python -m pipeline.segmenter eval --data data/truthsets/pybullet/dev
    python -m pipeline.segmenter train --data ... --device cuda --workers 14 --channels 24 48 64 96 \
        --batch 64 --max-minutes 3 --time-schedule          # on a GPU machine (scripts/segmenter_gpu.py)
    python -m pipeline.segmenter ensemble a.pt b.pt --out ab.pt

The shipped weights are ``pipeline/weights/segmenter.pt`` (``DEFAULT_WEIGHTS``), with a card beside
them (``segmenter.md``: data, steps, time, scores); ``segmenter_wide.pt`` (``WIDE_WEIGHTS``) is a wider
network trained on a GPU, chosen with ``realvideo.segmenter_weights: wide``.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import re
import time
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from pipeline import frame_realism
from pipeline.atomic import atomic_path, write_json
from pipeline.video import read_video

DEFAULT_WEIGHTS = Path(__file__).resolve().parent / "weights" / "segmenter.pt"
"""The shipped checkpoint (package data)."""

WIDE_WEIGHTS = DEFAULT_WEIGHTS.parent / "segmenter_wide.pt"
"""The wider network trained on a GPU (package data; card ``segmenter.md``), ``realvideo.segmenter_weights: wide``."""

CHANNELS = (12, 24, 32, 48)


class SegmenterError(RuntimeError):
    """A checkpoint is missing or does not fit the network."""


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True),
                         nn.Conv2d(cout, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class UNet(nn.Module):
    """The segmenter network (module docstring): ``(B, 4, H, W)`` -> ``(B, 2, H, W)`` logits.

    Args:
        channels: feature channels per level, finest first (the checkpoint stores them).
    """

    def __init__(self, channels: tuple[int, ...] = CHANNELS, inputs: int = 4, outputs: int = 2) -> None:
        super().__init__()
        self.channels = tuple(int(c) for c in channels)
        self.down = nn.ModuleList()
        c = inputs
        for k in channels:
            self.down.append(_block(c, k))
            c = k
        self.up = nn.ModuleList(_block(channels[i] + channels[i - 1], channels[i - 1])
                                for i in range(len(channels) - 1, 0, -1))
        self.head = nn.Conv2d(channels[0], outputs, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for i, block in enumerate(self.down):
            x = block(x if i == 0 else F.max_pool2d(x, 2))
            skips.append(x)
        for block, skip in zip(self.up, reversed(skips[:-1])):
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = block(torch.cat([x, skip], dim=1))
        return self.head(x)


def median_background(frames: np.ndarray, max_frames: int = 120) -> np.ndarray:
    """``(H, W, 3)`` uint8 per-pixel median of up to ``max_frames`` frames spread over ``(N, H, W, 3)``."""
    idx = np.unique(np.linspace(0, len(frames) - 1, min(len(frames), max_frames)).round().astype(int))
    return np.median(frames[idx], axis=0).astype(np.uint8)


def network_input(frames: np.ndarray, background: np.ndarray) -> np.ndarray:
    """``(T, 4, H, W)`` float32 network input of ``(T, H, W, 3)`` uint8 RGB frames and their
    ``(H, W, 3)`` uint8 background (module docstring)."""
    f = frames.astype(np.float32)
    b = background.astype(np.float32)[None]
    sigma = max(0.5, 0.002 * min(frames.shape[1:3]))
    blur = lambda x: np.stack([cv2.GaussianBlur(i, (0, 0), sigma) for i in x])  # noqa: E731
    diff = np.abs(blur(f) - blur(b)).max(axis=-1, keepdims=True) / 255.0
    x = np.concatenate([f / 255.0 - 0.5, diff], axis=-1)
    return np.ascontiguousarray(x.transpose(0, 3, 1, 2))


CONTACT_PX = 2
"""Contact target: object pixels within this many px (chessboard distance) of another object."""


def targets(seg: np.ndarray, contact_px: int = CONTACT_PX) -> np.ndarray:
    """``(T, 2, H, W)`` float32 training targets of ``(T, H, W)`` int labels: foreground, and
    contact (within ``contact_px`` px of a pixel of another object)."""
    seg = np.asarray(seg)
    fg = seg >= 0
    kernel = np.ones((2 * contact_px + 1, 2 * contact_px + 1), np.uint8)
    contact = np.zeros_like(fg)
    for t in range(len(seg)):
        s = seg[t].astype(np.int16)
        for k in np.unique(s[s >= 0]):
            own = (s == k).astype(np.uint8)
            other = ((s >= 0) & (s != k)).astype(np.uint8)
            near_other = cv2.dilate(other, kernel) > 0
            near_own = cv2.dilate(own, kernel) > 0
            contact[t] |= (own > 0) & near_other | (other > 0) & near_own
    return np.stack([fg, contact], axis=1).astype(np.float32)


class Segmenter:
    """A loaded segmenter: :meth:`__call__` gives per-pixel probabilities.

    A checkpoint holds one network (``{"channels", "state_dict"}``) or an ensemble
    (``{"members": [{"channels", "state_dict"}, ...]}``, :func:`ensemble`), whose probabilities are
    the mean of its members'.

    Args:
        weights: checkpoint path (default :data:`DEFAULT_WEIGHTS`).
    Raises:
        SegmenterError: the file is missing or its tensors do not fit :class:`UNet`.
    """

    def __init__(self, weights: str | Path | None = None) -> None:
        path = Path(weights) if weights is not None else DEFAULT_WEIGHTS
        if not path.is_file():
            raise SegmenterError(f"{path}: no segmenter checkpoint (train one: python -m pipeline.segmenter train)")
        try:
            ckpt = torch.load(path, map_location="cpu", weights_only=True)
            self.nets = []
            for member in ckpt.get("members", [ckpt]):
                net = UNet(tuple(member.get("channels", CHANNELS)))
                net.load_state_dict(member["state_dict"])
                self.nets.append(net.eval())
            if not self.nets:
                raise ValueError("an ensemble of no network")
        except Exception as exc:   # noqa: BLE001 - any unreadable checkpoint is one error
            raise SegmenterError(f"{path}: not a segmenter checkpoint ({exc})") from None
        self.path = path

    @property
    def net(self) -> UNet:
        """The network of a one-network checkpoint (what training and interpolation start from).

        Raises:
            SegmenterError: the checkpoint is an ensemble.
        """
        if len(self.nets) != 1:
            raise SegmenterError(f"{self.path}: an ensemble of {len(self.nets)} networks, not one network")
        return self.nets[0]

    @torch.no_grad()
    def __call__(self, frames: np.ndarray, background: np.ndarray, batch: int = 16) -> tuple[np.ndarray, np.ndarray]:
        """Probabilities of foreground and contact (an ensemble's: the mean of its members').

        Args:
            frames: ``(T, H, W, 3)`` uint8 RGB.
            background: ``(H, W, 3)`` uint8 background image of the clip (:func:`median_background`).
        Returns:
            ``(fg, contact)``: ``(T, H, W)`` float32 in [0, 1] each.
        """
        T, H, W = frames.shape[:3]
        ph, pw = (-H) % 8, (-W) % 8
        out = []
        for a in range(0, T, batch):
            x = torch.from_numpy(network_input(frames[a:a + batch], background))
            x = F.pad(x, (0, pw, 0, ph), mode="replicate")
            p = sum(torch.sigmoid(net(x)) for net in self.nets) / len(self.nets)
            out.append(p[:, :, :H, :W].numpy())
        p = np.concatenate(out)
        return p[:, 0], p[:, 1]


def ensemble(paths: list[Path], out: Path) -> dict:
    """Write one checkpoint holding the networks of ``paths`` (one-network checkpoints of any
    channels), whose probabilities :class:`Segmenter` averages, atomically.

    Averaging the predictions of independently trained networks (Lakshminarayanan et al.,
    "Simple and scalable predictive uncertainty estimation using deep ensembles", NeurIPS 2017)
    is more robust than either alone; unlike :func:`interpolate` the networks need not share an
    initialisation or a shape.

    Raises:
        SegmenterError: fewer than two paths, or a path is missing, not a checkpoint or an ensemble.
    """
    if len(paths) < 2:
        raise SegmenterError(f"ensemble: needs at least two checkpoints, got {len(paths)}")
    nets = [Segmenter(p).net for p in paths]
    members = [{"channels": list(net.channels), "state_dict": net.state_dict()} for net in nets]
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out, suffix=".pt") as tmp:
        torch.save({"members": members}, tmp)
    return {"members": [str(p) for p in paths], "channels": [m["channels"] for m in members], "out": str(out)}


def resolve_weights(choice: str | None, root: str | Path | None = None) -> Path | None:
    """The checkpoint of a ``realvideo.segmenter_weights`` value: None (or ``shipped``) keeps the
    default (:data:`DEFAULT_WEIGHTS`, returned as None), ``wide`` is :data:`WIDE_WEIGHTS`, any other
    value a path, relative to ``root`` (the params file's folder) unless absolute."""
    if choice is None or choice == "shipped":
        return None
    if choice == "wide":
        return WIDE_WEIGHTS
    path = Path(choice)
    return path if path.is_absolute() or root is None else Path(root) / path


_SHIPPED: dict[str, Segmenter] = {}


def shipped(weights: str | Path | None = None) -> Segmenter:
    """The segmenter of the checkpoint ``weights`` (default :data:`DEFAULT_WEIGHTS`), loaded
    once per process and kept by path. The observation (``pipeline.observe``) takes one as its
    ``segmenter`` argument; the main job passes the one of ``realvideo.segmenter_weights``.

    Raises:
        SegmenterError: the file is missing or not a segmenter checkpoint.
    """
    key = str(Path(weights) if weights is not None else DEFAULT_WEIGHTS)
    if key not in _SHIPPED:
        _SHIPPED[key] = Segmenter(key)
    return _SHIPPED[key]


# ------------------------------------------------------------------------------ training
def _read_clip(folder: Path, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """``(frames (T, H, W, 3) uint8, seg (T, H, W) int16)`` of a rendered clip folder at ``size = (W, H)``."""
    truth = np.load(folder / "truth.npz")
    frames = read_video(folder / "video.mp4", size=size, crop=(0, 0, *truth["seg"].shape[:0:-1])).frames
    seg = np.stack([cv2.resize(s.astype(np.int16), size, interpolation=cv2.INTER_NEAREST)
                    for s in truth["seg"][: len(frames)]])
    return frames, seg


def clip_folders(data: list[Path]) -> list[Path]:
    """The complete clip folders (``clip-NNNNN`` with ``truth.npz`` and ``video.mp4``) of set folders;
    the temporary folder of a clip whose writer was killed is not one."""
    return sorted(c for d in data for c in Path(d).iterdir()
                  if re.fullmatch(r"clip-\d+", c.name) and (c / "truth.npz").is_file() and (c / "video.mp4").is_file())


def _clip_inputs(job: tuple[Path, tuple[int, int], int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Network inputs ``(per_clip, 4, H, W)`` float16 and targets ``(per_clip, 2, H, W)`` uint8 of
    ``per_clip`` frames of one clip folder, drawn with ``seed`` (a pool task of :func:`_load_set`)."""
    folder, size, per_clip, seed = job
    frames, seg = _read_clip(folder, size)
    bg = median_background(frames)
    pick = np.random.default_rng(seed).choice(len(frames), size=min(per_clip, len(frames)), replace=False)
    return network_input(frames[pick], bg).astype(np.float16), targets(seg[pick]).astype(np.uint8)


def _load_set(folders: list[Path], size: tuple[int, int], per_clip: int, rng: np.random.Generator,
              workers: int = 0):
    """Frames, backgrounds and targets of rendered clips at ``size = (W, H)``, read in ``workers``
    processes (0: in this one); the frames taken per clip depend on ``rng`` only, not on ``workers``."""
    jobs = [(folder, size, per_clip, int(s)) for folder, s in zip(folders, rng.integers(0, 2**31, len(folders)))]
    if workers > 0:
        with multiprocessing.get_context("spawn").Pool(workers) as pool:
            parts = pool.map(_clip_inputs, jobs, chunksize=4)
    else:
        parts = [_clip_inputs(job) for job in jobs]
    return np.concatenate([x for x, _ in parts]), np.concatenate([y for _, y in parts])


class _Batches(torch.utils.data.IterableDataset):
    """An endless stream of augmented training batches ``(x (B, 4, 120, 160) float32, y (B, 2, 120,
    160) float32)`` drawn from the loaded frames; each DataLoader worker draws its own stream
    (seed + worker id), so batch making scales with the CPU cores while the network trains."""

    def __init__(self, X: torch.Tensor, Y: torch.Tensor, batch: int, seed: int, realism: bool,
                 realism_fraction: float) -> None:
        super().__init__()
        self.X, self.Y, self.batch, self.seed = X, Y, batch, seed
        self.realism, self.realism_fraction = realism, realism_fraction

    def __iter__(self):
        info = torch.utils.data.get_worker_info()
        seed = self.seed + (0 if info is None else 1000 * (info.id + 1))
        gen = torch.Generator().manual_seed(seed)
        rng = np.random.default_rng(seed)
        if info is not None:                    # one thread per batch-making process
            torch.set_num_threads(1)
            cv2.setNumThreads(1)
        while True:
            idx = torch.randint(0, len(self.X), (self.batch,), generator=gen)
            x, y = _augment(self.X[idx], self.Y[idx], gen)
            if self.realism and rng.random() < self.realism_fraction:
                xn, yn = x.numpy().copy(), y.numpy().copy()
                frame_realism.realism(xn, yn, rng)
                x, y = torch.from_numpy(xn), torch.from_numpy(yn)
            yield x, y


def _augment(x: torch.Tensor, y: torch.Tensor, gen: torch.Generator, out: tuple[int, int] = (160, 120)
             ) -> tuple[torch.Tensor, torch.Tensor]:
    """Random flips, a random crop of 35-100 % of the frame resized to ``out = (W, H)`` (objects
    appear at 0.5-1.4 times their size in the clip, as the working crop and size make them), and
    colour jitter (gain, offset, some greyscale, noise)."""
    if torch.rand(1, generator=gen) < 0.5:
        x, y = x.flip(-1), y.flip(-1)
    B, _, H, W = x.shape
    s = float(torch.empty(1).uniform_(0.35, 1.0, generator=gen))
    h, w = max(8, int(H * s)), max(8, int(W * s))
    i = int(torch.randint(0, H - h + 1, (1,), generator=gen))
    j = int(torch.randint(0, W - w + 1, (1,), generator=gen))
    x = F.interpolate(x[:, :, i:i + h, j:j + w].float(), size=out[::-1], mode="bilinear", align_corners=False)
    y = F.interpolate(y[:, :, i:i + h, j:j + w].float(), size=out[::-1], mode="nearest")
    gain = torch.empty(B, 3, 1, 1).uniform_(0.7, 1.3, generator=gen)
    shift = torch.empty(B, 3, 1, 1).uniform_(-0.15, 0.15, generator=gen)
    rgb = ((x[:, :3] + 0.5) * gain + shift).clamp(0, 1) - 0.5
    grey = torch.rand(B, 1, 1, 1, generator=gen) < 0.15          # some clips are greyscale
    rgb = torch.where(grey, rgb.mean(1, keepdim=True).expand_as(rgb), rgb)
    noise = torch.randn(rgb.shape, generator=gen) * 0.02
    return torch.cat([rgb + noise, x[:, 3:]], dim=1), y


STATIC_DIFF = 0.04
"""Difference channel (max RGB difference from the median background, 0..1) below which an object
pixel is *static*: the background holds it, so only its appearance can mark it (:func:`loss_fn`)."""


def loss_fn(logits: torch.Tensor, y: torch.Tensor, x: torch.Tensor | None = None,
            still_weight: float = 1.0) -> torch.Tensor:
    """Binary cross-entropy of both maps (contact weighted x5, it is rare) plus a soft Dice loss of
    the foreground (Milletari et al. 2016), so small objects weigh as much as large ones.

    Args:
        logits: ``(B, 2, H, W)`` float network output (foreground, contact).
        y: ``(B, 2, H, W)`` float targets in {0, 1} (:func:`targets`).
        x: ``(B, 4, H, W)`` float network input (:func:`network_input`); needed if ``still_weight != 1``.
        still_weight: weight of the foreground cross-entropy on *static* object pixels (target 1 and
            difference channel below :data:`STATIC_DIFF`): an object at rest is in the median
            background, so the difference channel says nothing about it, and with weight 1 the network
            learns that no difference means background (issue 36: still objects at pitch 53-86 deg were
            missed whole). Other pixels weigh 1.
    Returns:
        scalar float loss.
    Raises:
        SegmenterError: ``still_weight != 1`` without ``x``, or ``still_weight < 1``.
    """
    if still_weight < 1.0:
        raise SegmenterError(f"still_weight: must be >= 1, got {still_weight}")
    weight = None
    if still_weight != 1.0:
        if x is None:
            raise SegmenterError("still_weight: needs the network input x (its difference channel)")
        static = (y[:, 0] > 0.5) & (x[:, 3] < STATIC_DIFF)
        weight = 1.0 + (still_weight - 1.0) * static.float()
    bce = F.binary_cross_entropy_with_logits(logits[:, 0], y[:, 0], weight=weight) + \
        F.binary_cross_entropy_with_logits(logits[:, 1], y[:, 1], pos_weight=torch.tensor(5.0))
    p = torch.sigmoid(logits[:, 0])
    inter = (p * y[:, 0]).sum(dim=(1, 2))
    dice = 1 - (2 * inter + 1) / (p.sum(dim=(1, 2)) + y[:, 0].sum(dim=(1, 2)) + 1)
    return bce + dice.mean()


def train(data: list[Path], out: Path, steps: int = 3000, batch: int = 12, lr: float = 3e-3,
          size: tuple[int, int] = (320, 240), per_clip: int = 12, seed: int = 0,
          max_minutes: float | None = None, log_every: int = 50, init: Path | None = None,
          realism: bool = False, realism_fraction: float = 1.0, channels: tuple[int, ...] = CHANNELS,
          device: str = "cpu", workers: int = 0, time_schedule: bool = False, mp_context: str = "spawn",
          still_weight: float = 1.0) -> dict:
    """Train the segmenter on rendered clips and save the checkpoint atomically.

    Args:
        data: folders holding clip folders (``video.mp4`` + ``truth.npz``, :mod:`pipeline.truthsets`).
        out: checkpoint path (``.pt``); a card ``<out>.json`` is written beside it.
        steps, batch, lr: AdamW steps, images per step, peak learning rate (cosine decay).
        size: ``(W, H)`` px the clips are read at (crops of them are resized to 160 x 120, :func:`_augment`).
        per_clip: frames taken per clip.
        max_minutes: stop early after this much wall time.
        init: checkpoint to start from (fine-tuning; its channels win), else random initialisation.
        realism: add static scenery, camera noise and zoom-out (:func:`pipeline.frame_realism.realism`)
            to a ``realism_fraction`` of the batches.
        channels: U-Net channels per level for a network from scratch.
        device: torch device of the network (``cpu``, ``cuda``); batches are made on the CPU.
        workers: processes that read the clips and make the batches (0: this one; the batch stream
            then depends on ``seed`` alone).
        mp_context: how batch-making processes start: ``spawn`` (safe in any process; the frames go
            to shared memory) or ``fork`` (copy-on-write, no shared memory needed; only in a fresh
            process: a child forked after the parent ran OpenMP work can hang in it).
        time_schedule: with ``max_minutes``, the cosine decay runs over the wall time instead of the
            steps, so a run on a machine of unknown speed ends its schedule at the deadline
            (``steps`` is then only an upper bound; the card records the steps done).
        still_weight: weight of static object pixels in the foreground loss (:func:`loss_fn`).
    Returns:
        the card dict (data, steps done, seconds, final losses).
    Raises:
        SegmenterError: no clip folder in ``data``, a bad ``init`` checkpoint, ``time_schedule``
            without ``max_minutes``, or ``still_weight < 1``.
    """
    if still_weight < 1.0:
        raise SegmenterError(f"still_weight: must be >= 1, got {still_weight}")
    if time_schedule and max_minutes is None:
        raise SegmenterError("time_schedule: needs max_minutes (the deadline the schedule ends at)")
    if not 0.0 <= realism_fraction <= 1.0:
        raise SegmenterError(f"realism_fraction: must be in [0, 1], got {realism_fraction}")
    torch.manual_seed(seed)
    torch.set_num_threads(max(1, torch.get_num_threads()))
    rng = np.random.default_rng(seed)
    folders = clip_folders(data)
    if not folders:
        raise SegmenterError(f"{', '.join(map(str, data))}: no clip folders with truth.npz")
    t0 = time.time()
    X, Y = _load_set(folders, size, per_clip, rng, workers)
    print(f"[segmenter] {len(X)} frames from {len(folders)} clips in {time.time() - t0:.0f} s", flush=True)
    X, Y = torch.from_numpy(X), torch.from_numpy(Y)
    net = Segmenter(init).net.train() if init is not None else UNet(channels)
    net = net.to(device)
    if str(device).startswith("cuda"):
        torch.backends.cudnn.benchmark = True     # fixed batch shape: let cuDNN pick its kernels
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=1e-4)
    stream = torch.utils.data.DataLoader(_Batches(X, Y, batch, seed, realism, realism_fraction), batch_size=None,
                                         num_workers=workers, pin_memory=device != "cpu",
                                         persistent_workers=workers > 0,
                                         multiprocessing_context=mp_context if workers > 0 else None)
    t1 = time.time()
    history = []
    done = 0
    for step, (x, y) in enumerate(stream):
        elapsed = time.time() - t1
        if step >= steps or (max_minutes is not None and elapsed > 60 * max_minutes):
            break
        progress = elapsed / (60 * max_minutes) if time_schedule else step / steps
        for g in opt.param_groups:
            g["lr"] = lr * 0.5 * (1 + math.cos(math.pi * min(1.0, progress)))
        x, y = x.to(device, non_blocking=True), y.to(device, non_blocking=True)
        loss = loss_fn(net(x), y, x, still_weight)
        opt.zero_grad()
        loss.backward()
        opt.step()
        done = step + 1
        history.append(loss.item())
        if done % log_every == 0:
            print(f"[segmenter] step {done}/{steps} loss {np.mean(history[-log_every:]):.4f} "
                  f"{(time.time() - t1) / done:.3f} s/step", flush=True)
        if done % 500 == 0:
            _save(net, out)
    _save(net, out)
    card = {"data": [str(d) for d in data], "clips": len(folders), "frames": int(len(X)), "size": list(size),
            "steps": done, "batch": batch, "lr": lr, "seconds": round(time.time() - t1, 1),
            "first_loss": round(float(np.mean(history[:10])), 4) if history else None,
            "final_loss": round(float(np.mean(history[-100:])), 4) if history else None,
            "parameters": int(sum(p.numel() for p in net.parameters())), "threads": torch.get_num_threads(),
            "per_clip": per_clip, "contact_px": CONTACT_PX, "init": str(init) if init is not None else None,
            "realism": realism, "realism_fraction": realism_fraction if realism else 0.0,
            "channels": list(net.channels), "device": str(device), "workers": workers,
            "schedule": "time" if time_schedule else "steps", "mp_context": mp_context,
            "still_weight": still_weight}
    write_json(out.with_suffix(".json"), card)
    return card


def _save(net: UNet, out: Path) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().cpu() for k, v in net.state_dict().items()}
    with atomic_path(out, suffix=".pt") as tmp:
        torch.save({"channels": list(net.channels), "state_dict": state}, tmp)


def interpolate(a: Path, b: Path, out: Path, alpha: float = 0.5) -> dict:
    """Write the checkpoint ``(1 - alpha) * a + alpha * b`` (every float tensor, batch-norm
    statistics included; integer tensors from ``b``), atomically.

    Weight-space interpolation between a model and its fine-tuned copy (WiSE-FT, Wortsman et al.,
    "Robust fine-tuning of zero-shot models", CVPR 2022) keeps much of what each knows: here the
    renders-only weights and their fine-tune with :mod:`pipeline.frame_realism` (card:
    ``pipeline/weights/segmenter.md``).

    Raises:
        SegmenterError: a checkpoint is missing or the two do not have the same tensors.
    """
    if not 0.0 <= alpha <= 1.0:
        raise SegmenterError(f"alpha: must be in [0, 1], got {alpha}")
    na, nb = Segmenter(a).net.state_dict(), Segmenter(b).net.state_dict()
    if na.keys() != nb.keys() or any(na[k].shape != nb[k].shape for k in na):
        raise SegmenterError(f"{a}, {b}: not the same network")
    mixed = {k: ((1 - alpha) * na[k].float() + alpha * nb[k].float()).to(na[k].dtype)
             if na[k].is_floating_point() else nb[k] for k in na}
    net = UNet(Segmenter(a).net.channels)
    net.load_state_dict(mixed)
    _save(net, out)
    return {"a": str(a), "b": str(b), "alpha": alpha, "out": str(out)}


def evaluate(data: list[Path], weights: Path | None = None, size: tuple[int, int] = (320, 240)) -> dict:
    """Foreground IoU of the segmenter (threshold 0.5) per clip of rendered sets, and its mean."""
    seg_net = Segmenter(weights)
    folders = clip_folders(data)
    ious = []
    for folder in folders:
        frames, seg = _read_clip(folder, size)
        fg, _ = seg_net(frames, median_background(frames))
        p, t = fg > 0.5, seg >= 0
        ious.append(float((p & t).sum() / max(1, (p | t).sum())))
    return {"clips": len(folders), "foreground_iou": round(float(np.mean(ious)), 4) if ious else None,
            "per_clip": [round(v, 4) for v in ious]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m pipeline.segmenter", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("train", help="train on rendered clips (pipeline.truthsets folders)")
    t.add_argument("--data", type=Path, nargs="+", required=True)
    t.add_argument("--out", type=Path, default=DEFAULT_WEIGHTS)
    t.add_argument("--steps", type=int, default=3000)
    t.add_argument("--batch", type=int, default=12)
    t.add_argument("--lr", type=float, default=3e-3)
    t.add_argument("--max-minutes", type=float, default=None)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--per-clip", type=int, default=12, help="frames taken per clip")
    t.add_argument("--init", type=Path, default=None, help="checkpoint to fine-tune (default: from scratch)")
    t.add_argument("--realism", action="store_true",
                   help="add static scenery, camera noise and zoom-out to the batches (pipeline.frame_realism)")
    t.add_argument("--realism-fraction", type=float, default=1.0,
                   help="with --realism: the fraction of batches that get it (default %(default)s)")
    t.add_argument("--channels", type=int, nargs="+", default=list(CHANNELS),
                   help="U-Net channels per level, finest first, from scratch (default %(default)s)")
    t.add_argument("--device", default="cpu", help="torch device of the network: cpu, cuda (default %(default)s)")
    t.add_argument("--workers", type=int, default=0,
                   help="processes reading clips and making batches (default %(default)s: this one)")
    t.add_argument("--mp-context", choices=("spawn", "fork"), default="spawn",
                   help="how batch-making processes start (fork: copy-on-write frames, for a fresh process on a "
                        "machine with little shared memory; default %(default)s)")
    t.add_argument("--time-schedule", action="store_true",
                   help="with --max-minutes: the cosine decay runs over the wall time (deadline runs)")
    t.add_argument("--still-weight", type=float, default=1.0,
                   help="weight of static object pixels (no difference from the median background) in the "
                        "foreground loss (default %(default)s)")
    e = sub.add_parser("eval", help="foreground IoU on rendered clips")
    e.add_argument("--data", type=Path, nargs="+", required=True)
    e.add_argument("--weights", type=Path, default=None)
    en = sub.add_parser("ensemble", help="one checkpoint whose probabilities are the mean of several networks'")
    en.add_argument("members", type=Path, nargs="+")
    en.add_argument("--out", type=Path, required=True)
    m = sub.add_parser("interpolate", help="(1 - alpha) * A + alpha * B of two checkpoints (WiSE-FT)")
    m.add_argument("a", type=Path)
    m.add_argument("b", type=Path)
    m.add_argument("--alpha", type=float, default=0.5)
    m.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    if args.cmd in ("interpolate", "ensemble"):
        try:
            card = (interpolate(args.a, args.b, args.out, args.alpha) if args.cmd == "interpolate"
                    else ensemble(args.members, args.out))
        except SegmenterError as exc:
            print(f"error: {exc}")
            return 2
    elif args.cmd == "train":
        card = train(args.data, args.out, steps=args.steps, batch=args.batch, lr=args.lr,
                     max_minutes=args.max_minutes, seed=args.seed, per_clip=args.per_clip, init=args.init,
                     realism=args.realism, realism_fraction=args.realism_fraction,
                     channels=tuple(args.channels), device=args.device, workers=args.workers,
                     time_schedule=args.time_schedule, mp_context=args.mp_context,
                     still_weight=args.still_weight)
    else:
        card = evaluate(args.data, args.weights)
    print(json.dumps(card, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
