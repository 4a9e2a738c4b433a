"""Discrepancy workflow: find -> name -> add -> show (docs/design.md §8).

Measured trajectories go in; out come the places where the base model (scene language v1,
simulated by MuJoCo) disagrees with them, the missing physical effect(s) named from the
effect library (``pipeline.effects``) with fitted coefficients and confidence intervals, the
extended scenes (``effects:`` block) and a report showing the held-out gap shrink.

1. **Find.** Per clip, the base model's free parameters (each object's initial position,
   orientation, linear and angular velocity, ``material.damping`` and
   ``material.sliding_friction``) are fitted by least squares
   (``scipy.optimize.least_squares``, finite-difference Jacobian over MuJoCo rollouts of a
   model compiled once per clip and edited in place). The measurement noise is estimated from
   the data alone (:func:`estimate_noise`), and residual segments that exceed it are listed
   with the motion phase (flight, contact, sliding, rolling, rest).
2. **Name.** Candidate effects are screened cheaply (linearised gain), then each one left
   is profiled over its strength (every clip refitted from the data at each point), fitted
   jointly over all clips (its coefficients shared, the per-clip parameters free), scored in
   sample by BIC and out of sample by leave-one-clip-out (coefficients from the other clips'
   profile, only the clip's own parameters refitted). An effect is named only if it clears
   both gates (BIC drop and held-out chi-square drop above thresholds, i.e. above what the
   noise floor explains) and beats its own null value (a likelihood-ratio test, again in the
   final model); greedy forward selection repeats with the named effects in the model
   (:func:`run_workflow`). Isolated outliers are dropped first.
3. **Add.** The final joint fit (converged) gives the coefficients, with confidence intervals
   from the profile likelihood (:func:`profile_intervals`; the Gauss-Newton interval
   ``s^2 (J^T J)^-1`` of ``mujoco.sysid.calculate_intervals`` where the profile confirms it,
   open where the data cannot bound a side), reported widened by an allowance for model
   mismatch (``ci_model_error``), and one extended scene per clip.
4. **Show.** ``discrepancy.md`` / ``discrepancy.json``, residual plots before/after (PNG),
   a rerun recording (measured vs base vs extended). The shown gap (:attr:`Result.gap`) is
   the leave-one-clip-out held-out RMSE with >= 2 clips; with one clip there is nothing to
   hold out, so it is a forward split in time (:func:`forward_gap`: fitted on the clip's
   first part, the rest forecast). The in-sample RMSE with the number of fitted parameters
   of each model is always reported beside it (:attr:`Result.in_sample`).

Input: tables with columns ``clip, object, t, x, y, z`` (m, s, z up; CSV or Parquet), optional
``qw, qx, qy, qz`` (measured orientation, e.g. motion capture) and optional object columns
``shape, radius, width, depth, height, mass``; or two-dimensional Tracker exports (header names
the columns ``t`` and two of ``x``/``y``, y up, metres), mapped to x -> x, y -> z (world y is
not observed). Object sizes and masses may also come from an objects mapping
(:func:`parse_objects`). Bad input raises :class:`DiscrepancyInputError` with one line naming
the file and the column.

Example::

    clips = read_trajectories(["data/hidden/trajectories.parquet"])
    result = run_workflow(clips, DiscrepancyConfig())
    write_report(result, "reports")

Modules, in import order (each imports only those above it): ``config`` (settings),
``trajectories`` (objects, tracks, clips, :class:`DiscrepancyInputError`), ``noise`` (noise
estimate, outliers), ``readers`` (files and their checks, a 2-D export's floor), ``clip_model`` (the base model in MuJoCo, residuals), ``fit``
(least squares), ``find`` (motion phases, residual segments), ``workspace`` (compiled models,
worker pool, held-out scores), ``screen`` (cheap candidate screens), ``profile`` (profiles,
joint fits, held-out scores), ``intervals`` (profile-likelihood intervals, their coverage),
``forward`` (the single-clip forward gap), ``workflow`` (forward selection, :class:`Result`),
``hidden`` (hidden-effect data), ``independent`` (hidden-effect data from a hand-written
integrator that shares nothing with the MuJoCo model), ``plots``, ``report``, ``benchmark`` and ``cli``. This
package re-exports the public API below.
"""

from pipeline.discrepancy.benchmark import benchmark_markdown, run_benchmark, run_trial
from pipeline.discrepancy.cli import add_arguments, add_benchmark_arguments, benchmark_cli, load_config, main_cli
from pipeline.discrepancy.clip_model import NUISANCE, ClipModel, Weights, clip_residuals, clip_residuals_many
from pipeline.discrepancy.config import DISCREPANCY_DECIMALS, DefaultObject, DiscrepancyConfig
from pipeline.discrepancy.find import PHASES, motion_phases, residual_segments
from pipeline.discrepancy.fit import (Fit, clip_information, fit_clips, free_mask, initial_nuisance, newton_leave_one_out,
                                      single_threaded_blas)
from pipeline.discrepancy.forward import forward_gap
from pipeline.discrepancy.hidden import HIDDEN_KINDS, HiddenConfig, draw_effect, generate_hidden
from pipeline.discrepancy.intervals import profile_intervals
from pipeline.discrepancy.noise import Noise, estimate_noise
from pipeline.discrepancy.plots import plot_residuals, plot_trajectories, record
from pipeline.discrepancy.profile import Profile
from pipeline.discrepancy.readers import (clips_from_columns, clips_from_infer_dir, parse_objects, read_trajectories,
                                          read_trajectory_file)
from pipeline.discrepancy.report import extended_scenes, report_dict, report_markdown, write_report
from pipeline.discrepancy.screen import screen_candidates
from pipeline.discrepancy.trajectories import (MIN_SAMPLES, QUAT_COLUMNS, SPEC_COLUMNS, TABLE_COLUMNS, Clip,
                                               DiscrepancyInputError, ObjectSpec, Track)
from pipeline.discrepancy.workflow import Result, run_workflow
from pipeline.discrepancy.workspace import HeldOut, Workspace

__all__ = [
    "DISCREPANCY_DECIMALS", "HIDDEN_KINDS", "MIN_SAMPLES", "NUISANCE", "PHASES", "QUAT_COLUMNS", "SPEC_COLUMNS",
    "TABLE_COLUMNS", "Clip", "ClipModel", "DefaultObject", "DiscrepancyConfig", "DiscrepancyInputError", "Fit",
    "HeldOut", "HiddenConfig", "Noise", "ObjectSpec", "Profile", "Result", "Track", "Weights", "Workspace",
    "add_arguments", "add_benchmark_arguments", "benchmark_cli", "benchmark_markdown", "clip_residuals",
    "clip_information", "clip_residuals_many",
    "clips_from_columns", "clips_from_infer_dir", "draw_effect", "estimate_noise", "extended_scenes", "fit_clips",
    "forward_gap", "free_mask", "generate_hidden", "initial_nuisance", "load_config", "main_cli", "motion_phases",
    "newton_leave_one_out", "parse_objects", "plot_residuals", "plot_trajectories", "profile_intervals", "read_trajectories",
    "read_trajectory_file", "record", "report_dict", "report_markdown", "residual_segments", "run_benchmark",
    "run_trial", "run_workflow", "screen_candidates", "single_threaded_blas", "write_report",
]
