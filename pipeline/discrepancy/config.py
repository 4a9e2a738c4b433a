"""Settings of the discrepancy workflow (params section ``discrepancy``) and the decimals of
the scenes it writes."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from pipeline import effects as fx
from pipeline.mjcf import SimOptions
from pipeline.scene import Decimals


DISCREPANCY_DECIMALS = Decimals(position=4, orientation=4, velocity=3, damping=6, friction=3, mass=6, size=5,
                                effect=4, duration=3)
"""Decimals of the written extended scenes (finer than the model target: they are fits)."""


class StrictModel(BaseModel):
    """Base of the discrepancy settings models: unknown keys are refused (pydantic
    ``ValidationError``) and instances are frozen (immutable, hashable)."""

    model_config = ConfigDict(extra="forbid", frozen=True)


class DefaultObject(StrictModel):
    """Object assumed when the input gives no size/mass (flagged in the report)."""

    radius: float = Field(0.02, gt=0, description="m, sphere/cylinder radius")
    width: float = Field(0.1, gt=0, description="m, box")
    depth: float = Field(0.1, gt=0, description="m, box")
    height: float = Field(0.05, gt=0, description="m, box/cylinder")
    mass: float = Field(0.05, gt=0, description="kg")


class DiscrepancyConfig(StrictModel):
    """Workflow settings (params section ``discrepancy``).

    Attributes:
        candidates: effect names tried (default: the whole library).
        max_effects: most effects named by greedy forward selection.
        noise_floor_chi2: after naming an effect, stop when every clip's chi2 per residual
            is at most this (the model fits every clip to the noise floor).
        bic_threshold: an effect must lower BIC by at least this much (10 = "very strong"
            evidence, Kass & Raftery 1995).
        heldout_threshold: ... and lower the held-out chi-square (noise-normalised squared
            residuals of clips not used to fit its coefficients) by at least this much.
        segment_p: residuals are flagged where a window's chi-square tail probability under
            the noise model is below this.
        segment_window: samples per window (:func:`residual_segments`).
        min_segment_samples: shortest flagged segment, samples.
        contact_tolerance: m; an object is on the floor when its lowest point is closer.
        rest_speed: m/s; below it an object on the floor is at rest.
        max_nfev: function evaluations per least-squares fit of the base model.
        max_nfev_warm: ... per warm-started fit (profile refits, held-out refits). These two
            caps are for the cheap screening fits (profile points, continuation horizons).
        ftol: relative cost tolerance of the *converged* fits (scipy ``ftol``; ``xtol`` and
            ``gtol`` are set 100x smaller): the base model's last horizon, every candidate's
            joint fit, the final fit and the profile-likelihood points stop on it. 1e-5 of a
            clip's chi-square (~500 for 1.5 s at 60 Hz) is 0.005 per step, of 8 clips' ~0.04,
            a hundredth of the interval threshold (3.84) and far below the gates (10); a few
            fits crawl in small steps above 1e-6 (one clip refitted at a profile point of the
            8-clip drag set of ``benchmarks/discrepancy_speed.py``: 45 evaluations at 1e-6,
            26 at 1e-5; the 8 clips summed to 4306.995 instead of 4306.908). The workflow
            names the same effects with the same intervals there (to 1e-4 of wind_y) in 10 %
            less time (was 1e-6).
        max_nfev_converged: safety cap (function evaluations) of a converged fit; a fit that
            reaches it reports ``status`` 0 in the report (``optimizer``).
        screen_ftol: relative cost tolerance of the screening fits.
        threads: MuJoCo rollout threads (the joint fits, in the main process).
        workers: processes that fit the clips one by one in parallel (per-clip fits: the base
            fit, every profile point); ``None``: every available core. 1: no pool.
        screen_gain: a candidate gets its full fits only when the linearised screen
            (:func:`screen_candidates`) predicts a chi-square gain of at least this much, or,
            failing that, the clips refitted from the data at one strength of it
            (:func:`second_chance_point`) gain that much (0: every candidate is fitted).
        race: fit the candidates that pass the screen in the order of their predicted gain
            and stop as soon as an eligible one fits every clip to the noise floor
            (``noise_floor_chi2``) while the screen predicts every untried one to gain less
            than ``race_margin`` times its realised chi-square gain; the untried ones (and the
            second chances of those the screen rejected) are reported as ``deferred``. Off:
            every candidate passing the screen gets its full fits (the selection differs only
            where a deferred candidate, under-predicted by the screen, would have had a lower
            BIC).
        race_margin: see ``race``.
        race_excess: an eligible candidate also ends the race (with >= 2 clips; and a named
            model the search) when it leaves at most this fraction of the chi-square excess above the noise
            (``sum_c max(chi2_c - n_c, 0)``) that the model before it left: it explains the
            rest, and what is left is model mismatch no other candidate would explain better
            (0: only the per-clip noise floor ends them).
        mismatch_terms: nuisance terms (``pipeline.effects``, ``Effect.nuisance``: e.g.
            ``scale_error``) of the mismatch check: an eligible candidate's profile gain
            (every clip refitted from the data) must exceed the best term's, profiled the same
            way on the current model, by ``mismatch_margin`` in chi-square (empty: no check).
        mismatch_margin: see ``mismatch_terms``.
        rescreen_all: after the first step, try every remaining candidate again (default:
            only those whose profile improved the base model by ``heldout_threshold``).
        horizons: fractions of each clip fitted in turn by the per-clip fits (continuation,
            :meth:`Workspace.fit_clip`). The first is short enough to end before most
            clips' first impact: an initial velocity estimated from the first 6 samples is a
            few cm/s off, which moves the first bounce, and a fit whose first horizon holds
            that bounce stalls in its wrong basin (a throw with wind: chi2 7081 for 546
            residuals from (0.5, 1); 478 from (0.2, 0.4, 0.7, 1), the value at the truth).
        forward_split: with a single clip (nothing to hold out) the shown gap is a forecast:
            base and base + named effects are fitted on the clip's first ``forward_split``
            of its duration and scored on the samples after it (:func:`forward_gap`).
        hold_damping: hold every object's ``material.damping`` at 0 instead of fitting it
            (the variant of :func:`forward_gap` in which an effect with
            ``Effect.replaces_damping`` stands in for the linear damping).
        diff_step: finite-difference step, in units of each parameter's scale.
        jac_refresh: a least-squares fit's Jacobian is a full finite-difference one on every
            ``jac_refresh``-th call and a Broyden update of the last one in between (1: always
            finite differences, the default; :func:`pipeline.discrepancy.fit.fit_clips`). Measured,
            not adopted: 2 took the drag set 0.48x the time, but the wind set's fit ended in another
            optimum (held-out gap 1.07 -> 2.36 mm) at 0.93x (``docs/discrepancy.md``).
        ci_level: confidence level of the coefficient intervals.
        contact_timeconst: s, ``solref`` time constant of the base model's object and floor
            contacts in the workflow's fits (critically damped); the params ``sim`` value
            (0.02 s, the scenes' default) lets a 5 g ball that lands at 4 m/s sink 16-23 mm
            into the floor and creep out over 0.2 s, which turns its spin into the wrong rolling
            speed (0.23 m/s for 0.35 by angular momentum about the contact point); at 0.005 s it
            sinks 3 mm. Stiffer still (0.0034 s, twice the 1/600 s step) launches a ball that
            starts sliding by ~1 cm. The base fits of independent data (impulse bounces, no
            effect) reach chi2/n 0.9-4 instead of up to 900 (:func:`fit_options`).
        timestep: s, upper bound of the fits' physics step (the largest step at most this
            that divides a clip's sample interval is used, ``pipeline.mjcf.frame_timestep``);
            None: params ``sim.timestep`` (1/600 s). The rollouts are four fifths of a
            dataset's time, and their cost is proportional to the number of steps.
            MuJoCo keeps a contact's time constant at least twice the step (``refsafe``), so
            a step above ``contact_timeconst / 2`` changes the contact.
        friction_cone: MuJoCo friction cone of the fits: ``elliptic`` (isotropic Coulomb
            friction) or ``pyramidal`` (the scenes' default; 4 edges: a sphere sliding off the
            edges' axes feels a different friction, 10 mm over 0.2 s on independent data).
        ci_model_error: relative allowance for model mismatch added to every reported
            interval: the smallest interval holding the profile's and ``v +- ci_model_error *
            max(|v|, scale)`` (:func:`pipeline.discrepancy.intervals.with_model_error`; the
            profile's own is kept as ``ci_profile``). 0.3: on data from an independent
            integrator (``discrepancy-benchmark --engine independent``) the profile intervals
            held the truth in 25 of 79 correctly named coefficients at nominal 95 %, widened by
            0.2 / 0.3 / 0.4 in 69 / 71 / 73; six of the eight left out at 0.3 are torsional
            friction, which MuJoCo's elliptic cone shares with sliding.
        ci_jackknife: with >= 3 clips, also report the leave-one-clip-out jackknife interval
            (:func:`pipeline.discrepancy.intervals.jackknife_intervals`, ``ci_jackknife``), a
            diagnostic: with clips of different kinds, leaving out the one clip that carries an
            effect sends the estimate to its default, and the interval to the bounds.
        null_test: an eligible effect must also beat its own null value: every clip refitted
            from the candidate's joint fit with the effect removed (its other effects held at
            the joint fit's values) must be worse by at least the chi-square quantile of
            ``ci_level`` with as many degrees of freedom as the effect has coefficients,
            times the candidate's residual variance factor s^2 = chi2 / dof (the profile
            likelihood's test that the interval excludes the null value; Venzon & Moolgavkar
            1988). An effect whose gain comes from refitting the rest (its fitted value at or
            near its null value) is not named.
        outlier_sigma: before anything is fitted, a sample is dropped as an outlier when it
            lies more than this many prediction standard deviations from a quadratic through
            its six nearest neighbours while those fit it within the noise (a spike in smooth
            motion; a bounce is kept), with the noise estimated robustly from the data
            (:func:`pipeline.discrepancy.noise.find_outliers`); 0: keep every sample.
        default_object: size and mass assumed when the input has none.
        recording: write the rerun recording.
    """

    candidates: tuple[str, ...] = fx.EFFECTS
    max_effects: int = Field(3, ge=0)
    noise_floor_chi2: float = Field(1.3, gt=0)
    bic_threshold: float = Field(10.0, ge=0)
    heldout_threshold: float = Field(10.0, ge=0)
    segment_p: float = Field(1e-3, gt=0, lt=1)
    min_segment_samples: int = Field(2, ge=1)
    segment_window: int = Field(5, ge=1)
    contact_tolerance: float = Field(0.005, gt=0)
    rest_speed: float = Field(0.05, gt=0)
    max_nfev: int = Field(15, ge=2)
    max_nfev_warm: int = Field(10, ge=2)
    ftol: float = Field(1e-5, gt=0, lt=1)
    max_nfev_converged: int = Field(100, ge=2)
    screen_ftol: float = Field(1e-4, gt=0, lt=1)
    threads: int = Field(2, ge=1)
    workers: int | None = Field(None, ge=1)
    rescreen_all: bool = False
    race: bool = True
    race_margin: float = Field(0.5, gt=0)
    race_excess: float = Field(0.05, ge=0, lt=1)
    mismatch_terms: tuple[str, ...] = ("scale_error",)
    mismatch_margin: float = Field(10.0, ge=0)
    screen_gain: float = Field(10.0, ge=0)
    horizons: tuple[float, ...] = (0.2, 0.4, 0.7, 1.0)
    forward_split: float = Field(0.6, gt=0, lt=1)
    hold_damping: bool = False
    diff_step: float = Field(1e-2, gt=0)
    jac_refresh: int = Field(1, ge=1)
    ci_level: float = Field(0.95, gt=0, lt=1)
    contact_timeconst: float = Field(0.005, gt=0)
    timestep: float | None = Field(None, gt=0, le=0.01)
    friction_cone: str = Field("elliptic", pattern="^(pyramidal|elliptic)$")
    ci_model_error: float = Field(0.3, ge=0)
    ci_jackknife: bool = True
    null_test: bool = True
    outlier_sigma: float = Field(6.0, ge=0)
    default_object: DefaultObject = DefaultObject()
    recording: bool = True

    def model_post_init(self, _ctx: Any) -> None:
        for name in self.candidates:
            if name not in fx.EFFECTS:
                raise ValueError(f"candidates: unknown effect {name!r}, must be one of "
                                 f"{', '.join(fx.EFFECTS)}")
        for name in self.mismatch_terms:
            if name not in fx.REGISTRY or not fx.REGISTRY[name].nuisance:
                raise ValueError(f"mismatch_terms: {name!r} is not a nuisance term, must be one of "
                                 f"{', '.join(n for n, c in fx.REGISTRY.items() if c.nuisance)}")


def fit_options(options: SimOptions | None, cfg: DiscrepancyConfig) -> SimOptions:
    """The simulation options of the workflow's fits: ``options`` (params ``sim``) untextured,
    with the base contact of ``cfg`` (``contact_timeconst``, critically damped, on objects and
    floor; ``friction_cone``; ``timestep`` where set). Hidden-effect data made for a benchmark
    of the workflow use the same options, so that its base model is the generator's."""
    solref = (float(cfg.contact_timeconst), 1.0)
    update = {"textured": False, "object_solref": solref, "floor_solref": solref, "cone": cfg.friction_cone}
    if cfg.timestep is not None:
        update["timestep"] = float(cfg.timestep)
    return (options or SimOptions()).model_copy(update=update)
