"""RAFT: Recurrent All-Pairs Field Transforms for optical flow, written here in torch.

Teed & Deng, "RAFT: Recurrent All-Pairs Field Transforms for Optical Flow", ECCV 2020
(arXiv:2003.12039). The network has four parts (paper §3):

1. a **feature encoder** ``fnet`` and a **context encoder** ``cnet``, both at 1/8 resolution;
2. the **all-pairs correlation volume** of the two feature maps, pooled into a 4-level pyramid
   (paper §3.2, eq. 1), looked up in a ``(2r+1)^2`` window around the current estimate;
3. a **ConvGRU update operator** that refines the flow iteratively (paper §3.3);
4. **convex upsampling** of the 1/8 flow to full resolution with a learned 3x3 convex
   combination per pixel (paper §3.3, "Upsampling"); the small variant of the authors' release
   upsamples bilinearly instead.

Two variants, with the module names of the authors' release so that their checkpoints load by
key (``pipeline.raft.weights``):

=========  ==================  ===========  =====  ======  ==================
variant    encoders            GRU          r      hidden  upsampling
=========  ==================  ===========  =====  ======  ==================
``small``  bottleneck 32-64-96  ConvGRU 3x3  3      96      bilinear (or convex)
``basic``  residual 64-96-128   SepConvGRU   4      128     convex
=========  ==================  ===========  =====  ======  ==================

``small`` with ``convex=True`` is this project's variant: the small network plus the basic
variant's mask head scaled to its hidden size (images here are 96x64, a 12x8 grid at 1/8, where
bilinear upsampling smears small objects).

Shapes: images ``(N, 3, H, W)`` float in [0, 255], ``H`` and ``W`` multiples of 8 (the caller
pads, :func:`pipeline.raft.weights.RaftFlow`); flow ``(N, 2, H, W)`` float px, channel 0 = u
(x, right), channel 1 = v (y, down), forward from image 1 to image 2.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn


@dataclass(frozen=True)
class RaftArch:
    """Architecture of one RAFT variant.

    Attributes:
        small: bottleneck encoders, ConvGRU, radius 3 (``raft-small``); else the basic network
            (``raft-things``, ``raft-sintel``, ...).
        convex: convex upsampling (a mask head ``update_block.mask``); the official small
            network has none and upsamples bilinearly.
    """

    small: bool = True
    convex: bool = True

    @property
    def hidden_dim(self) -> int:
        """Channels of the GRU state."""
        return 96 if self.small else 128

    @property
    def context_dim(self) -> int:
        """Channels of the context features fed to every GRU step."""
        return 64 if self.small else 128

    @property
    def corr_levels(self) -> int:
        """Levels of the correlation pyramid."""
        return 4

    @property
    def corr_radius(self) -> int:
        """Look-up radius r at every level (window ``(2r+1)^2``)."""
        return 3 if self.small else 4

    @property
    def corr_planes(self) -> int:
        """Correlation features per pixel: ``levels * (2r+1)^2``."""
        return self.corr_levels * (2 * self.corr_radius + 1) ** 2


# ---------------------------------------------------------------------------------------
# Encoders (paper §3.1)
# ---------------------------------------------------------------------------------------


def _norm(kind: str, channels: int) -> nn.Module:
    """Normalisation layer by name; ``none`` is an empty Sequential (no state-dict keys)."""
    if kind == "instance":
        return nn.InstanceNorm2d(channels)          # affine=False: no parameters, as released
    if kind == "batch":
        return nn.BatchNorm2d(channels)
    if kind == "group":
        return nn.GroupNorm(num_groups=max(channels // 8, 1), num_channels=channels)
    if kind == "none":
        return nn.Sequential()
    raise ValueError(f"norm: must be instance, batch, group or none, got {kind!r}")


class ResidualBlock(nn.Module):
    """Two 3x3 convolutions with a skip (1x1 strided projection when ``stride > 1``)."""

    def __init__(self, cin: int, cout: int, norm: str, stride: int = 1) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, padding=1, stride=stride)
        self.conv2 = nn.Conv2d(cout, cout, 3, padding=1)
        self.norm1, self.norm2 = _norm(norm, cout), _norm(norm, cout)
        self.downsample = None
        if stride != 1:
            self.norm3 = _norm(norm, cout)
            self.downsample = nn.Sequential(nn.Conv2d(cin, cout, 1, stride=stride), self.norm3)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.norm1(self.conv1(x)))
        y = F.relu(self.norm2(self.conv2(y)))
        return F.relu((x if self.downsample is None else self.downsample(x)) + y)


class BottleneckBlock(nn.Module):
    """1x1 -> 3x3 (strided) -> 1x1 convolutions at a quarter of the width, with a skip."""

    def __init__(self, cin: int, cout: int, norm: str, stride: int = 1) -> None:
        super().__init__()
        mid = cout // 4
        self.conv1 = nn.Conv2d(cin, mid, 1)
        self.conv2 = nn.Conv2d(mid, mid, 3, padding=1, stride=stride)
        self.conv3 = nn.Conv2d(mid, cout, 1)
        self.norm1, self.norm2, self.norm3 = _norm(norm, mid), _norm(norm, mid), _norm(norm, cout)
        self.downsample = None
        if stride != 1:
            self.norm4 = _norm(norm, cout)
            self.downsample = nn.Sequential(nn.Conv2d(cin, cout, 1, stride=stride), self.norm4)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.norm1(self.conv1(x)))
        y = F.relu(self.norm2(self.conv2(y)))
        y = F.relu(self.norm3(self.conv3(y)))
        return F.relu((x if self.downsample is None else self.downsample(x)) + y)


class Encoder(nn.Module):
    """A 7x7 stride-2 stem and three stages of two blocks (strides 1, 2, 2): 1/8 resolution.

    Args:
        widths: channels of the stem and the three stages, ``(32, 32, 64, 96)`` (small,
            bottleneck blocks) or ``(64, 64, 96, 128)`` (basic, residual blocks).
        out_dim: channels of the final 1x1 convolution.
        norm: ``instance`` (feature encoder), ``batch`` (basic context encoder) or ``none``.
    """

    def __init__(self, widths: tuple[int, int, int, int], out_dim: int, norm: str, bottleneck: bool) -> None:
        super().__init__()
        block = BottleneckBlock if bottleneck else ResidualBlock
        stem, w1, w2, w3 = widths
        self.conv1 = nn.Conv2d(3, stem, 7, stride=2, padding=3)
        self.norm1 = _norm(norm, stem)
        self.layer1 = nn.Sequential(block(stem, w1, norm, 1), block(w1, w1, norm, 1))
        self.layer2 = nn.Sequential(block(w1, w2, norm, 2), block(w2, w2, norm, 1))
        self.layer3 = nn.Sequential(block(w2, w3, norm, 2), block(w3, w3, norm, 1))
        self.conv2 = nn.Conv2d(w3, out_dim, 1)
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
                nn.init.zeros_(m.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = F.relu(self.norm1(self.conv1(x)))
        return self.conv2(self.layer3(self.layer2(self.layer1(x))))


# ---------------------------------------------------------------------------------------
# Correlation pyramid (paper §3.2)
# ---------------------------------------------------------------------------------------


def coords_grid(n: int, h: int, w: int, device: torch.device | None = None) -> torch.Tensor:
    """Pixel coordinates ``(n, 2, h, w)`` float: channel 0 = x (column), 1 = y (row)."""
    ys, xs = torch.meshgrid(torch.arange(h, device=device, dtype=torch.float32),
                            torch.arange(w, device=device, dtype=torch.float32), indexing="ij")
    return torch.stack([xs, ys]).unsqueeze(0).expand(n, -1, -1, -1)


def sample_at(img: torch.Tensor, xy: torch.Tensor) -> torch.Tensor:
    """Bilinear samples of ``img (B, C, H, W)`` at pixel coordinates ``xy (B, h, w, 2)`` (x, y),
    zero outside: ``(B, C, h, w)``. A side of length 1 reads its only pixel."""
    h, w = img.shape[-2:]
    gx = 2 * xy[..., 0] / max(w - 1, 1) - 1
    gy = 2 * xy[..., 1] / max(h - 1, 1) - 1
    return F.grid_sample(img, torch.stack([gx, gy], dim=-1), mode="bilinear", align_corners=True)


class CorrPyramid:
    """All-pairs correlation ``C_ij = <g_i, g'_j> / sqrt(D)`` (paper eq. 1), average-pooled over
    the second image's dimensions into ``levels`` levels.

    Looking up at coordinates ``(N, 2, h, w)`` returns ``(N, levels*(2r+1)^2, h, w)``: per level,
    the ``(2r+1) x (2r+1)`` window around ``coords / 2^level``, flattened with its first axis
    along x and its second along y (the channel order of the authors' release, which their
    weights expect).
    """

    def __init__(self, fmap1: torch.Tensor, fmap2: torch.Tensor, levels: int, radius: int) -> None:
        n, d, h, w = fmap1.shape
        corr = torch.einsum("ndp,ndq->npq", fmap1.reshape(n, d, h * w), fmap2.reshape(n, d, h * w))
        corr = (corr / d ** 0.5).reshape(n * h * w, 1, h, w)
        self.pyramid = [corr]
        for _ in range(levels - 1):
            corr = F.avg_pool2d(corr, 2, stride=2) if min(corr.shape[-2:]) >= 2 else corr
            self.pyramid.append(corr)
        self.radius = radius
        d = torch.arange(-radius, radius + 1, dtype=torch.float32, device=fmap1.device)
        dx, dy = torch.meshgrid(d, d, indexing="ij")       # window axis 0 along x, axis 1 along y
        self.delta = torch.stack([dx, dy], dim=-1)          # (2r+1, 2r+1, 2) = (x, y) offsets

    def __call__(self, coords: torch.Tensor) -> torch.Tensor:
        n, _, h, w = coords.shape
        centre = coords.permute(0, 2, 3, 1).reshape(n * h * w, 1, 1, 2)
        k = 2 * self.radius + 1
        out = []
        for level, corr in enumerate(self.pyramid):
            win = sample_at(corr, centre / 2 ** level + self.delta)         # (nhw, 1, k, k)
            out.append(win.reshape(n, h, w, k * k))
        return torch.cat(out, dim=-1).permute(0, 3, 1, 2).contiguous()


# ---------------------------------------------------------------------------------------
# Update operator (paper §3.3)
# ---------------------------------------------------------------------------------------


class FlowHead(nn.Module):
    """Two 3x3 convolutions: GRU state -> flow increment ``(N, 2, h, w)``."""

    def __init__(self, cin: int, hidden: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, hidden, 3, padding=1)
        self.conv2 = nn.Conv2d(hidden, 2, 3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv2(F.relu(self.conv1(x)))


class ConvGRU(nn.Module):
    """Convolutional GRU with 3x3 gates (paper §3.3, eqs. for z, r, q, h)."""

    def __init__(self, hidden: int, cin: int) -> None:
        super().__init__()
        self.convz = nn.Conv2d(hidden + cin, hidden, 3, padding=1)
        self.convr = nn.Conv2d(hidden + cin, hidden, 3, padding=1)
        self.convq = nn.Conv2d(hidden + cin, hidden, 3, padding=1)

    def forward(self, h: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        hx = torch.cat([h, x], dim=1)
        z, r = torch.sigmoid(self.convz(hx)), torch.sigmoid(self.convr(hx))
        q = torch.tanh(self.convq(torch.cat([r * h, x], dim=1)))
        return (1 - z) * h + z * q


class SepConvGRU(nn.Module):
    """Two ConvGRU steps with separable 1x5 then 5x1 gates (the basic variant)."""

    def __init__(self, hidden: int, cin: int) -> None:
        super().__init__()
        for axis, (kernel, pad) in (("1", ((1, 5), (0, 2))), ("2", ((5, 1), (2, 0)))):
            for gate in "zrq":
                setattr(self, f"conv{gate}{axis}", nn.Conv2d(hidden + cin, hidden, kernel, padding=pad))

    def forward(self, h: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        for axis in "12":
            hx = torch.cat([h, x], dim=1)
            z = torch.sigmoid(getattr(self, f"convz{axis}")(hx))
            r = torch.sigmoid(getattr(self, f"convr{axis}")(hx))
            q = torch.tanh(getattr(self, f"convq{axis}")(torch.cat([r * h, x], dim=1)))
            h = (1 - z) * h + z * q
        return h


class MotionEncoder(nn.Module):
    """Correlation features and the current flow -> motion features (the flow is appended)."""

    def __init__(self, arch: RaftArch) -> None:
        super().__init__()
        self.small = arch.small
        if arch.small:
            self.convc1 = nn.Conv2d(arch.corr_planes, 96, 1)
            self.convf1 = nn.Conv2d(2, 64, 7, padding=3)
            self.convf2 = nn.Conv2d(64, 32, 3, padding=1)
            self.conv = nn.Conv2d(128, 80, 3, padding=1)
        else:
            self.convc1 = nn.Conv2d(arch.corr_planes, 256, 1)
            self.convc2 = nn.Conv2d(256, 192, 3, padding=1)
            self.convf1 = nn.Conv2d(2, 128, 7, padding=3)
            self.convf2 = nn.Conv2d(128, 64, 3, padding=1)
            self.conv = nn.Conv2d(64 + 192, 128 - 2, 3, padding=1)

    @property
    def out_dim(self) -> int:
        """Channels returned: 80 + 2 (small) or 126 + 2 (basic)."""
        return self.conv.out_channels + 2

    def forward(self, flow: torch.Tensor, corr: torch.Tensor) -> torch.Tensor:
        cor = F.relu(self.convc1(corr))
        if not self.small:
            cor = F.relu(self.convc2(cor))
        flo = F.relu(self.convf2(F.relu(self.convf1(flow))))
        return torch.cat([F.relu(self.conv(torch.cat([cor, flo], dim=1))), flow], dim=1)


class UpdateBlock(nn.Module):
    """Motion encoder + GRU + flow head (+ the convex-upsampling mask head)."""

    def __init__(self, arch: RaftArch) -> None:
        super().__init__()
        self.encoder = MotionEncoder(arch)
        gru_in = arch.context_dim + self.encoder.out_dim
        self.gru = ConvGRU(arch.hidden_dim, gru_in) if arch.small else SepConvGRU(arch.hidden_dim, gru_in)
        self.flow_head = FlowHead(arch.hidden_dim, 128 if arch.small else 256)
        self.mask = None
        if arch.convex:
            self.mask = nn.Sequential(nn.Conv2d(arch.hidden_dim, 256, 3, padding=1), nn.ReLU(),
                                      nn.Conv2d(256, 64 * 9, 1))

    def forward(self, net, inp, corr, flow, with_mask: bool = True):
        """``(net, mask | None, delta_flow)``; the mask only when ``with_mask`` (an iterate that
        is upsampled)."""
        net = self.gru(net, torch.cat([inp, self.encoder(flow, corr)], dim=1))
        mask = None
        if self.mask is not None and with_mask:
            mask = 0.25 * self.mask(net)   # the release scales the mask by 0.25 to balance gradients
        return net, mask, self.flow_head(net)


def upsample_convex(flow: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Full-resolution flow ``(N, 2, 8h, 8w)`` from ``flow (N, 2, h, w)`` at 1/8: each fine pixel
    is a convex combination (softmax of ``mask (N, 9*64, h, w)``) of its coarse 3x3 neighbours,
    times 8 (paper §3.3)."""
    n, _, h, w = flow.shape
    weights = torch.softmax(mask.view(n, 1, 9, 8, 8, h, w), dim=2)
    nb = F.unfold(8 * flow, (3, 3), padding=1).view(n, 2, 9, 1, 1, h, w)
    up = (weights * nb).sum(dim=2)                                   # (n, 2, 8, 8, h, w)
    return up.permute(0, 1, 4, 2, 5, 3).reshape(n, 2, 8 * h, 8 * w)


def upsample_bilinear(flow: torch.Tensor) -> torch.Tensor:
    """``(N, 2, h, w)`` -> ``(N, 2, 8h, 8w)``, values times 8 (the released small network)."""
    h, w = flow.shape[-2:]
    return 8 * F.interpolate(flow, size=(8 * h, 8 * w), mode="bilinear", align_corners=True)


class RAFT(nn.Module):
    """The RAFT network; ``state_dict()`` keys are those of the authors' release minus the
    ``module.`` prefix of their ``DataParallel`` checkpoints."""

    def __init__(self, arch: RaftArch = RaftArch()) -> None:
        super().__init__()
        self.arch = arch
        hdim, cdim = arch.hidden_dim, arch.context_dim
        widths = (32, 32, 64, 96) if arch.small else (64, 64, 96, 128)
        self.fnet = Encoder(widths, 128 if arch.small else 256, "instance", bottleneck=arch.small)
        self.cnet = Encoder(widths, hdim + cdim, "none" if arch.small else "batch", bottleneck=arch.small)
        self.update_block = UpdateBlock(arch)

    @staticmethod
    def normalise(images: torch.Tensor) -> torch.Tensor:
        """RGB in [0, 255] -> [-1, 1], as the release feeds its encoders."""
        return 2 * (images / 255.0) - 1

    def forward(self, image1: torch.Tensor, image2: torch.Tensor, iters: int = 12,
                flow_init: torch.Tensor | None = None, all_iters: bool = True) -> list[torch.Tensor]:
        """Flow estimates after each of ``iters`` updates.

        Args:
            image1, image2: ``(N, 3, H, W)`` float RGB in [0, 255]; ``H, W`` multiples of 8.
            iters: GRU updates (the release uses 12 at test time).
            flow_init: optional ``(N, 2, H/8, W/8)`` starting flow at 1/8 resolution (px there).
            all_iters: upsample every iterate (training: the sequence loss needs them all);
                ``False`` upsamples only the last (inference; about a third faster).

        Returns:
            ``iters`` tensors (or 1 when ``all_iters`` is False) ``(N, 2, H, W)`` float32 px,
            the last the final estimate.

        Raises:
            ValueError: sizes not multiples of 8 or the images' shapes differ.
        """
        if image1.shape != image2.shape or image1.shape[-1] % 8 or image1.shape[-2] % 8:
            raise ValueError(f"images: need equal shapes with H, W multiples of 8, got "
                             f"{tuple(image1.shape)} and {tuple(image2.shape)}")
        x1 = self.normalise(image1)
        fmap1, fmap2 = self.fnet(torch.cat([x1, self.normalise(image2)], dim=0)).chunk(2, dim=0)
        return self.refine(fmap1, fmap2, self.cnet(x1), iters, flow_init, all_iters)

    def refine(self, fmap1: torch.Tensor, fmap2: torch.Tensor, context: torch.Tensor, iters: int = 12,
               flow_init: torch.Tensor | None = None, all_iters: bool = False) -> list[torch.Tensor]:
        """The iterative part of :meth:`forward`, from encoded features.

        ``fmap1, fmap2``: ``fnet`` outputs ``(N, D, H/8, W/8)`` of the two images; ``context``:
        ``cnet`` output of image 1 ``(N, hidden + context, H/8, W/8)``. A video's frames can be
        encoded once each and paired here (``fnet`` normalises every image on its own).
        """
        a = self.arch
        corr_fn = CorrPyramid(fmap1.float(), fmap2.float(), a.corr_levels, a.corr_radius)
        net, inp = torch.split(context, [a.hidden_dim, a.context_dim], dim=1)
        net, inp = torch.tanh(net), torch.relu(inp)
        n, _, h, w = fmap1.shape
        coords0 = coords_grid(n, h, w, fmap1.device)
        coords1 = coords0 if flow_init is None else coords0 + flow_init
        out = []
        for i in range(iters):
            coords1 = coords1.detach()
            flow = coords1 - coords0
            net, mask, delta = self.update_block(net, inp, corr_fn(coords1), flow,
                                                 with_mask=all_iters or i == iters - 1)
            coords1 = coords1 + delta
            if all_iters or i == iters - 1:
                flow = coords1 - coords0
                out.append(upsample_bilinear(flow) if mask is None else upsample_convex(flow, mask))
        return out
