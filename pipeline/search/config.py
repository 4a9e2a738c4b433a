"""Search space settings: the params section ``search`` (:class:`SearchConfig`), the box around
the starting scene (:class:`SearchRanges`) and the field groups CMA-ES may free
(:data:`FREE_FIELDS`)."""

from __future__ import annotations

from typing import Literal, get_args

from pydantic import BaseModel, ConfigDict, Field

from pipeline.sample_config import TEST_SPLITS

FreeField = Literal["position", "linear_velocity", "angular_velocity", "yaw", "size", "camera",
                    "mass", "friction", "damping", "restitution", "exposure"]
FREE_FIELDS: tuple[str, ...] = get_args(FreeField)
"""Field groups CMA-ES may search (``search.free``)."""


class SearchRanges(BaseModel):
    """Half-widths of the search box around the starting scene (params ``search.ranges``).

    Attributes:
        position: m, per coordinate (z is kept at or above the height where the object
            touches the floor, :func:`floor_height`).
        linear_velocity: m/s, per component.
        angular_velocity: rad/s, per component.
        yaw: deg, rotation of the object about world z.
        size_factor: sizes vary in ``[s / f, s * f]`` (searched in log space).
        mass_factor: masses vary in ``[m / f, m * f]`` (log space).
        friction: sliding friction (dimensionless), kept >= 0.
        damping: freejoint damping, kept >= 0.
        camera_height: m (paper camera form).
        camera_position: m per coordinate (6-DoF camera form).
        camera_angle: deg, pitch (and yaw/roll of a 6-DoF camera).
        fov: deg, vertical field of view.
        restitution: coefficient of restitution ``e`` of a ``restitution`` effect, and a static
            geom's ``restitution`` (a bumper), within the effect's bounds
            (:data:`pipeline.effects.REGISTRY`).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    position: float = Field(0.25, ge=0)
    linear_velocity: float = Field(1.0, ge=0)
    angular_velocity: float = Field(5.0, ge=0)
    yaw: float = Field(45.0, ge=0, le=180)
    size_factor: float = Field(1.5, ge=1)
    mass_factor: float = Field(3.0, ge=1)
    friction: float = Field(0.5, ge=0)
    damping: float = Field(0.5, ge=0)
    camera_height: float = Field(0.15, ge=0)
    camera_position: float = Field(0.15, ge=0)
    camera_angle: float = Field(5.0, ge=0)
    fov: float = Field(8.0, ge=0)
    restitution: float = Field(0.2, ge=0)


class SearchConfig(BaseModel):
    """Params section ``search`` (test-time refinement).

    Attributes:
        k: samples per scene considered by Best@K (the first ``k`` by sample index; paper 32).
        popsize: CMA-ES population per iteration (paper 128).
        iterations: CMA-ES iterations (paper 100). Evaluations per scene:
            ``1 + popsize * iterations``.
        sigma: initial CMA-ES step size in the normalised [0, 1] search space.
        lambda_epe: weight of the flow EPE (1/px at the rendered resolution) in the fitness;
            1 is the paper's IoU − EPE (measured in px at its 480x320, where the same motion
            is 5x more px than at 96x64).
        prior_weight: weight of the mean squared normalised distance to the starting scene
            (the model's prediction), a prior against drifting where masks do not constrain.
        free: field groups searched (see :data:`FREE_FIELDS`); mass, friction and damping are
            not identified by masks (docs/design.md §10) and stay fixed by default.
        ranges: the search box (:class:`SearchRanges`).
        penalize_extra: in the fitness, predicted objects that match no observed object count
            as IoU 0 (see :func:`fitness`).
        fitness_iou: the IoU the fitness uses: ``strict`` (per object over the frames where it
            or its match is visible, no credit for agreeing on absence; issue 29 item 7) or
            ``all_frames`` (docs/design.md §7's full-sequence IoU, where a frame with both
            masks empty counts 1.0).
        epe_pixels: where the fitness's EPE is averaged: ``union`` (docs/design.md §7's
            :func:`pipeline.metrics.flow_epe`, pixels where either clip is foreground) or
            ``observed`` (the observed foreground only; a predicted object elsewhere adds
            pixels of zero error to the union and so lowers its mean: a large still object
            away from the motion beat every overlapping proposal on a real drop, issue 29).
        splits: dataset splits the best_of_k / cmaes stages process.

    Defaults are the small profile: 1 + 8 x 6 = 49 evaluations, ~3-4 s per scene at 96x64 on
    2 cores. ``sigma`` 0.05 and ``lambda_epe`` 1 did best in a sweep on perturbed synthetic
    scenes with DIS flow (sigma 0.03-0.1, lambda 0.05-2); ``prior_weight`` 5-20 made no
    difference there beyond noise, so it is off.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    k: int = Field(4, ge=1)
    popsize: int = Field(8, ge=2)
    iterations: int = Field(6, ge=0)
    sigma: float = Field(0.05, gt=0, le=1)
    lambda_epe: float = Field(1.0, ge=0)
    prior_weight: float = Field(0.0, ge=0)
    free: tuple[FreeField, ...] = ("position", "linear_velocity", "yaw", "size", "camera")
    ranges: SearchRanges = SearchRanges()
    penalize_extra: bool = True
    fitness_iou: Literal["strict", "all_frames"] = "strict"
    epe_pixels: Literal["union", "observed"] = "union"
    splits: tuple[str, ...] = TEST_SPLITS
