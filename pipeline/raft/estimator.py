"""RAFT checkpoints (the authors' key layout or ours) and flow of a clip's frames.

Checkpoints are plain torch state dicts with the module names of the authors' release
(princeton-vl/RAFT). Their files (``raft-small.pth``, ``raft-things.pth``, ``raft-sintel.pth``,
``raft-kitti.pth``, ``raft-chairs.pth``) were saved from ``nn.DataParallel`` and carry a
``module.`` prefix on every key; this project's own weights (``pipeline/weights/raft-small-dynamics.pth``)
are the same layout without it. The variant is read from the keys: bottleneck encoder blocks
(``fnet.layer1.0.conv3``) mean ``small``, a mask head (``update_block.mask.0``) means convex
upsampling.

Use a released checkpoint: put the file anywhere and set ``flow.raft_weights`` in params.yaml
(or ``dynamics infer --raft-weights PATH``); nothing is downloaded.

Example::

    net = RaftFlow.from_file("raft-things.pth")
    flow = net(frames)           # frames (T, H, W, 3) uint8 -> (T-1, H, W, 2) float32 px
"""

from __future__ import annotations

import functools
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from pipeline.flow import RAFT_ITERS
from pipeline.raft.model import RAFT, RaftArch

WEIGHTS_DIR = Path(__file__).resolve().parent.parent / "weights"
DEFAULT_WEIGHTS = WEIGHTS_DIR / "raft-small-dynamics.pth"
"""The weights trained here (card: ``pipeline/weights/raft-small-dynamics.md``)."""

MIN_GRID = 16
"""Cells on the short side of RAFT's 1/8 grid below which the frames are upscaled first: a
96x64 frame would be a 12x8 grid, where an object of 10 px covers one or two cells."""


class RaftWeightsError(ValueError):
    """A checkpoint file that is missing or is not a RAFT state dict."""


def arch_of(state: dict) -> RaftArch:
    """The :class:`RaftArch` a state dict (keys without ``module.``) was saved from."""
    return RaftArch(small="fnet.layer1.0.conv3.weight" in state, convex="update_block.mask.0.weight" in state)


def read_state(path: str | Path) -> dict[str, torch.Tensor]:
    """A RAFT state dict from ``path``, ``module.`` prefixes removed.

    Accepts a bare state dict (the release's files, ours) or a dict holding one under
    ``state_dict`` / ``model``.

    Raises:
        RaftWeightsError: missing file, unreadable file, or no RAFT keys in it.
    """
    path = Path(path)
    if not path.is_file():
        raise RaftWeightsError(f"{path}: flow.raft_weights: no such file (put raft-small.pth / raft-things.pth there)")
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - any unpickling error means "not a checkpoint"
        raise RaftWeightsError(f"{path}: flow.raft_weights: not a torch checkpoint ({type(e).__name__}: {e})") from None
    if isinstance(obj, dict) and not any(k.endswith(".weight") for k in obj if isinstance(k, str)):
        obj = obj.get("state_dict", obj.get("model", obj))
    if not isinstance(obj, dict) or "fnet.conv1.weight" not in {k.removeprefix("module.") for k in obj}:
        raise RaftWeightsError(f"{path}: flow.raft_weights: not a RAFT state dict (no fnet.conv1.weight key)")
    return {k.removeprefix("module."): v for k, v in obj.items()}


def load_raft(path: str | Path) -> RAFT:
    """The RAFT network of a checkpoint, in eval mode, on the CPU.

    Raises:
        RaftWeightsError: see :func:`read_state`, or keys/shapes that do not fit the variant.
    """
    state = read_state(path)
    net = RAFT(arch_of(state))
    try:
        net.load_state_dict(state, strict=True)
    except RuntimeError as e:
        first = str(e).splitlines()[0]
        raise RaftWeightsError(f"{path}: flow.raft_weights: keys do not fit RAFT {arch_of(state)}: {first}") from None
    return net.eval()


def save_raft(net: RAFT, path: str | Path, data_parallel_prefix: bool = False) -> Path:
    """Write ``net``'s state dict (the release's layout; with ``module.`` when
    ``data_parallel_prefix``) to ``path`` via a temp file and rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {("module." if data_parallel_prefix else "") + k: v.detach().cpu().contiguous()
             for k, v in net.state_dict().items()}
    tmp = path.with_name(path.name + ".tmp")
    torch.save(state, tmp)
    tmp.replace(path)
    return path


def working_scale(height: int, width: int, min_grid: int = MIN_GRID) -> float:
    """Upscaling factor so that the short side of the 1/8 grid has at least ``min_grid`` cells
    (1.0 when it already has)."""
    return max(1.0, min_grid * 8 / min(height, width))


class RaftFlow:
    """Flow of consecutive frames with a RAFT network.

    Frames are upscaled by :func:`working_scale` (bilinear), padded to multiples of 8 by edge
    replication (centred, as the release's ``InputPadder``), each frame encoded once, the pairs
    refined in batches, and the flow cropped, resized back and divided by the scale.

    Args:
        net: the network (see :func:`load_raft`).
        iters: GRU updates per pair (:data:`pipeline.flow.RAFT_ITERS`; the release: 12 at test time).
        batch: pairs per forward pass.
        min_grid: see :func:`working_scale`.
    """

    def __init__(self, net: RAFT, iters: int = RAFT_ITERS, batch: int = 8, min_grid: int = MIN_GRID) -> None:
        self.net, self.iters, self.batch, self.min_grid = net.eval(), iters, batch, min_grid

    @classmethod
    def from_file(cls, path: str | Path | None = None, **kw) -> "RaftFlow":
        """Network of ``path`` (None: the weights trained here, :data:`DEFAULT_WEIGHTS`)."""
        return cls(_cached_net(str(Path(path or DEFAULT_WEIGHTS).resolve())), **kw)

    @torch.no_grad()
    def __call__(self, frames: np.ndarray) -> np.ndarray:
        """Forward flow between consecutive frames.

        Args:
            frames: ``(T, H, W, 3)`` uint8 RGB, ``T >= 2``.

        Returns:
            ``(T-1, H, W, 2)`` float32 px, ``(u, v)`` = (x, y) displacement from frame t to t+1.

        Raises:
            ValueError: bad shape or dtype, fewer than two frames.
        """
        frames = np.asarray(frames)
        if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
            raise ValueError(f"frames: must be (T, H, W, 3) uint8, got {frames.shape} {frames.dtype}")
        if len(frames) < 2:
            raise ValueError(f"frames: need at least 2 frames, got {len(frames)}")
        T, H, W = frames.shape[:3]
        s = working_scale(H, W, self.min_grid)
        h, w = (round(H * s), round(W * s)) if s > 1 else (H, W)
        x = torch.from_numpy(np.stack([cv2.resize(f, (w, h), interpolation=cv2.INTER_LINEAR) for f in frames])
                             if (h, w) != (H, W) else frames.copy()).permute(0, 3, 1, 2).float()
        ph, pw = (-h) % 8, (-w) % 8
        pad = (pw // 2, pw - pw // 2, ph // 2, ph - ph // 2)
        net = self.net
        x = F.pad(x.to(next(net.parameters()).device), pad, mode="replicate")   # the network's device
        out = np.empty((T - 1, H, W, 2), np.float32)
        for a in range(0, T - 1, self.batch):
            b = min(a + self.batch, T - 1)
            clip = RAFT.normalise(x[a:b + 1])
            fmaps = net.fnet(clip)
            flow = net.refine(fmaps[:-1], fmaps[1:], net.cnet(clip[:-1]), self.iters)[-1]
            flow = flow[:, :, pad[2]:pad[2] + h, pad[0]:pad[0] + w].permute(0, 2, 3, 1).cpu().numpy()
            for i, f in enumerate(flow):
                out[a + i] = (cv2.resize(f, (W, H), interpolation=cv2.INTER_AREA) / s) if (h, w) != (H, W) else f
        return out


@functools.lru_cache(maxsize=4)
def _cached_net(path: str) -> RAFT:
    """One network per checkpoint path per process (loading takes ~50 ms; clips are many)."""
    return load_raft(path)
