"""Diagnosis of a preset against measurements: where the model fails, which registered effect is missing.

``diagnose(preset, images, ...)`` answers "what differs between these silhouettes and the model P?"
(docs/diagnose.md, CONVENTIONS "Diagnosing against a reference"):

1. Where it fails. K posterior-predictive draws of P (the same draws, effect draws and placement noise as
   ``infer.evaluate`` with that seed) are draped once each; per image: best-of-K pixel MSE and IoU, drape
   coefficient / node count / node amplitude against the draws' 90 % interval, r(theta) of the measurement
   and of the best draw, and the residual's harmonic amplitudes k = 1..6 against the re-drape floor (the
   same harmonics of best draw vs the other draws: what re-draping alone puts there).
2. What is missing. For every registered effect not in P: a score (Lagrange-multiplier) test at the effect's
   off value. The draws are draped on one model with every candidate active at its off values (the base
   model bit for bit: tested) and rendered with the fitter's soft renderer. The score of draw k is the gradient,
   with respect to each candidate's parameters, of the excess pixel data term
       L_k = mean_i data(draw_k, measured_i) - mean_j data(draw_k, reference_j)
   where the references are J = max(PSEUDO_MIN, n) silhouettes of P's own predictive (other posterior draws with
   their own placement noise): what the measurement would look like if P were right. The pixel term is
   quadratic, so the draw's own image cancels: the score is B_k (mean reference - mean measured) / (sigma^2 N),
   B_k the draw's adjoint (image -> parameters), i.e. the mean measured silhouette's difference from the mean
   predicted one, seen through how each effect would move the draw. Why not the plain data term's gradient (the
   first version): its mean under "P is right" is not zero (it pulls towards effects that make the drape less
   variable, and the soft silhouette's halo pulls on every effect that moves the edge), and its per-draw scatter
   ignores that the n measured images are themselves one re-drape each: on control drapes of other placements
   every candidate came out "significant" (docs/diagnose.md, the confusion table).
   The mean score's covariance has two parts: S/K, the scores' covariance over the K draws (B_k varies), and
   Cov(measured)/n + Cov(reference)/J seen through the draws, estimated per draw from a scatter image (one pair
   of references and one pair of measured images, differences scaled so that the outer product has that
   expectation; a second reference pair stands in for the measurement when one image is given) back-propagated
   like the score: one more adjoint per draw, on the recorded rollout. Draws 2m and 2m + 1 share a scatter image
   and C_u is the mean of their symmetrised cross products (unbiased through the mean adjoint; score_test). The
   statistic is
       T^2 = gbar^T (S/K + C_u)^+ gbar                   (rank-aware, after scaling each parameter by its
                                                          prior scale; q = rank)
   with Hotelling's F approximation on K - 1 dof (minus the nuisance's) as its p-value: a sign-flip test of the
   draws would see only the first part. Per-draw gradients are exact but heavy-tailed (folds bifurcate), so
   their norms are capped at fit.json gradient_clip.factor x the median first, as the fitter does (the scatter
   with the same factor). The threshold is alpha = 0.01, Bonferroni-corrected over the candidates tested. A
   parameter without gradient at the off point (a tilt's azimuth at zero angle) drops out of the rank; the
   tilt's angle is therefore also scored with the azimuth turned by 90 degrees (the registry's
   `second_direction`), so both tilt directions are seen: the same rollout (the angle is off), its adjoint
   evaluated at both azimuths (ClothModel.backward's alternatives).
   The material is a nuisance: what a change of its overall bending scale explains (a drape coefficient off the
   measured one pulls on every effect that moves it) is projected out of each draw's score first (the efficient
   score, with the information estimated by the outer product of the per-draw gradients; one dof lost).
   The data term is the pixel term alone (the drape coefficient's term is not quadratic in the image).
2b. The step test. The score sees the mean silhouette's change at the off value (a first-moment test); effects
   that change the fold pattern (prestrain, a stiffness map, a plastic set) move the drape little to first order and
   a lot at a finite strength. So the same draws (material, P's effect draws, placement noise) are draped once more
   with each candidate's primary parameter at its registry moderate strength (and at minus it where the bounds
   allow; a tilt also turned; an effect whose axis is set by several parameters, bending_anisotropy's 2-fold axis
   and an offset's direction, steps each of the registry's `step_parameters` in turn, an offset also along the
   diagonals), forward only, and the change of each draw's pixel MSE is measured against every measured image,
   against P's own predictive silhouettes (STEP_REFERENCES_MIN of them, the score's and more) and against the
   re-drape floor's re-drapes of P's mean material. The statistic is the change's mean over the
   measured images minus its mean over the references (negative: the step brings the draws closer to the
   measurements than to what P itself drapes). Its null (step_specimen_test): under "P is right" the measured
   images are n re-drapes of one specimen drawn from P, so the statistic varies by the spread between specimens
   (the references' variance less the re-drapes') plus the spread between re-drapes over n; p integrates over
   both variances' uncertainty and is corrected for the choice among the effect's steps by their correlation
   (step_family_p: Sidak's for independent steps, fewer chances for steps that move the draws alike). (Until
   2026-11-28 p came from relabelling measured and reference images as if every measured image were a specimen of
   its own: too narrow where P is uncertain, it passed a crease step on circle3 drapes without a crease;
   docs/diagnose.md.) A
   candidate's p_value is min(1, 2 min(score p, step p)) (Bonferroni over its two tests); both are reported.
   Screened (a fine mesh or a whole library on a budget): when the budget pays for fewer than SCREEN_BELOW of the
   draws on every step, every candidate is screened on SCREEN_DRAWS of them, and those whose screen p is below
   SCREEN_P_MAX are confirmed on fresh draws (the next of the K), as many as the budget left pays for at the
   screen's measured drape time, less one evaluation per refit that may follow (refits_reserved: one per candidate
   the score test already makes significant, at least one; the least promising dropped while
   the confirmation would not double the draws; no confirmation drape starts once the reserved evaluations would no
   longer fit, and only draws draped on every confirmed step count): nothing is refitted unless something is significant, and on a
   fine mesh only the confirmation makes the fold-pattern effects significant. A confirmed candidate's step test is the full test on all its draws,
   exactly what it would be had every candidate been draped on them (tested); the others' step p is the screen's,
   raised to SCREEN_P_MAX where it is below (dropped for time), so screening can only withhold significance, never
   add it: P(reported step p < t) <= P(full test's p < t) for t < SCREEN_P_MAX. When even the screen's minimum
   (MIN_SAMPLES draws on every step) is more than the budget pays for, the step test runs on fewer steps
   (steps_within: the offset's diagonals first, then the candidates with the largest score p; the dropped ones keep
   their score p alone). (Measured before it, on circle3 the whole library left 2-3 draws per step:
   no step test, so the fold-pattern effects the score misses could not be found; docs/diagnose.md.)
2c. The 3D step test (with --meshes on the model's topology: the Cusick reconstructions are circle3's). Some
   effects change a drape's folds in depth and sharpness more than its outline (high_curvature_bending: the crests'
   and the edge's hinge angles; measured on fabric 4, docs/lab/fold-depth.md). The step drapes of 2b are compared
   a second time, by their fold features (fold_geometry.features: per band of rest radius the crest and hoop
   hinge angles' 95th / 99th percentiles, per material ring the mean height and the fold amplitude; the simulated
   drapes' angles taken with the measured meshes' vertex noise, mesh_noise_m): the distance of two drapes is the
   mean squared feature difference, each feature over its sd among P's own drapes (the references), and the
   statistic and p are 2b's with it in place of the pixel MSE (step_tests_3d; the quadratic's terms in the draw
   cancel, so the statistic is the step's mean feature change projected on how the measured meshes differ from
   P's drapes). A candidate's p_value is then min(1, 3 min(score p, step p, 3D step p)). Screened, the 3D step
   test is on the screen's draws for every candidate: the confirmation is chosen by the silhouettes' screen alone
   (measured on fabric 4 when either test could pass the screen: in 3D all eleven candidates passed, the
   confirmation took 430 s of the 600 and the refits were left one evaluation each), and a 3D p that chooses
   nothing needs no raising.
3. Refits. When at least one candidate is below the threshold (the data differ from P), the candidates with p
   below REFIT_P_MAX are refitted, up to MAX_REFITS of them in refit_order (the significant ones first, each group
   by the sum of their ranks by combined p and by the step test's p, then statistic; the candidates found in 3D,
   3b, re-sorted among their places by their 3D steps' change, refit_order_3d), under the time budget: the score test says that
   something differs, the refits say which effect explains it. Significant first since seed 701 on circle3: a crease
   step that passes near the threshold on drapes without a crease (p 0.002-0.012) went before the significant tilt
   and camera by its strong step statistic, and the tilt's refit was dropped for time (docs/diagnose.md). Neither test alone picks the refits well: the combined p saturated (the step test's
   labellings, its null until 2026-11-28, cannot go below 2 / C(n + J, n)) while the score's p goes far lower for effects with a first-order
   signature; the step statistic is one finite step's change, noisy where several effects move the drape alike.
   Measured on the confusion runs of seeds 631, 641 and 651 (docs/diagnose.md): of 16 significant cases, the true
   effect was outside the first three by p in 2 (offset and bending_anisotropy at seed 651, 5th; their step
   statistics were the strongest), outside them by step statistic in 1 (heterogeneity_map at seed 641, 5th), and
   within the first three by the rank sum in all 16 (chosen on these seeds; a fresh seed's check is in
   docs/diagnose.md). Effects with the same signature compete there: a 1-fold r(theta) residual is what a tilt, a
   density gradient and a 1-fold stiffness map all predict, and on six tilted drapes the density gradient's score
   was the larger (T^2 98 on 3 dof against the tilt's 21 on 2). Each refit is ``infer.FitJob`` with effects
   {name: None} (P's own effects fixed), starting from P's material (its mean log table, per-entry posterior sd and stretching table, no bending scale search)
   and holding it there (the material's learning rates x MATERIAL_LEARNING_RATE_FACTOR = 0): P's posterior is
   the material's prior and, in a refit of a few epochs, also its posterior. Measured: with the material free, a
   short refit's noisy material steps absorbed a 0.3 rad tilt (the fitted angle fell 0.15 -> 0.03 rad in 8
   epochs); held, it rose to 0.26 rad in 11 epochs. Only the effect's strength (and its bdp posterior sd) is
   fitted, with the pixel term alone. It starts at the step test's best step when that step brought the draws
   closer to the measurements (statistic < 0; the step with the most negative statistic, refit_start, since
   2026-11-29: until then the one with the smallest p); a directional effect (a tilt's four steps, bending_anisotropy's four
   in its (cos2, sin2) plane, an offset's eight) starts along the direction all its steps point to where their
   statistics follow a first harmonic around the plane (step_direction, since 2026-11-29: the best single step is
   off by up to half the steps' spacing, and a tilt's search scales only its angle). That choice is made on K
   drapes with placement noise, where the fit's own start search judges its candidates by one drape without it
   (measured on fabric 1, whose photos are 2-fold: started at zero, bending_anisotropy's refit went the wrong way,
   best-of-16 MSE 0.058 -> 0.062).
   Before its epochs such a refit searches along the step (refit.search, ``line_search``): the stepped
   parameters' distance from off times 0.5, 1, 1.5 and 2 (an effect that steps two parameters first turns its
   step by +-45 degrees in their plane; 3x / 0.25x when the best is at an end), then the parabola's vertex
   through the best and its neighbours, each point scored by the best-of-K MSE of K draws with a seed of their own
   (SEARCH_SEED_OFFSET: the choice is not made on the draws that judge the refit); the epochs start at the best
   point, or at the vertex when it scores within SEARCH_VERTEX_WITHIN of the re-drape floor of the best (since
   2026-11-29, late: the vertex pools three points' noise; the smallest of one set of draws stayed at 0.5x the
   step on density searches whose truth lay at 0.7-0.85x). Why: the pixel loss of a folded drape is rough in rest
   shape, offset and strain (a gradient step follows fold switches, docs/diagnose.md), and at seed 661 half of the
   warm-started refits ended worse than their start, so the strength reported was the step's moderate one (17-36 %
   off the truth). Five to eight forward evaluations, about 4 s each on circle1 with 16 draws. An effect with a
   search grid in the registry (search_grid_spacing: the offset, 2.5 mm out to 1.5 cm) searches its plane on the
   grid instead, with or without a step start (grid_search: every point on SEARCH_GRID_DRAWS draws of the search's
   seed, the SEARCH_GRID_FINALISTS best again on K; about 50 s on circle1): its landscape is basins 3-5 mm wide,
   and at seeds 781 and 791 every 1 cm step draped further from the data than the centred drape, so the line
   search from the best step ended on the wrong side. The refit is also
   evaluated at its start, on the base's draws, and when its end is worse the start is kept (refit.kept_start): a
   few epochs of Adam's sign-sized first steps on one noisy batch each can undo a good step (measured on fabric 1:
   from cos2 = +0.75, whose step brought the draws 0.009 closer, 4 epochs went to (1.19, 0.43) and a best-of-16 MSE
   above the base's). One more evaluation (K forward drapes) per warm-started refit.
   Each refit is evaluated like the base (same seed, P's camera and P's global log sd) and written as
   DIR/presets/<effect>.json. The comparison (result.comparison, since 2026-11-29 late) is on k_eval draws: the
   base is draped again on them, forward only, and the re-drape floor measured against them, where the time
   left when the refits begin pays for it (COMPARISON_SHARE of it for the base's and every refit's end and start
   evaluations; at least K, at most COMPARISON_SAMPLES_MAX), else on the base's own K. Why: a best-of-16 MSE
   differs by 0.003 between two seeds of the same preset, as much as the radial near twins differ; on 64 draws x 3
   seeds the density refits of seeds 761 and 771 beat the camera refits that had been ranked above them on 16
   (0.0138 / 0.0126 against 0.0153 / 0.0143) and seed 761's camera refit beat the density one (0.0140 against
   0.0147). An evaluation is forward drapes only (about 0.13 s a draw on circle1). mse_fall = (base best-of-k_eval
   MSE - refit's) / base's: the same draws' noise on both sides, so the comparison is paired. The final ranking puts
   the refits that lower the error first (largest fall first), then the rest in the score tests' order.
   ``recommended`` = the first of them when its fall is at least MIN_MSE_FALL and some candidate was significant (or
   it is a switch named with --candidates), and the MSE it removes is at least MIN_FALL_OF_REDRAPE of the re-drape
   floor, else None. ``alternatives`` are the other refits that lower the error with a best-of-K MSE above the
   recommended's by less than ALTERNATIVE_WITHIN of the floor (the same line): differences that re-draping makes, so
   the images do not tell them apart (the radial near twins, docs/diagnose.md seed 681). ``not_refitted`` names,
   beside a recommendation, the candidates with p below NEAR_THRESHOLD_FACTOR x the threshold whose refit did not
   run (unrefitted). The re-drape floor (base.redrape_mse) is the mean over REDRAPE_FLOOR_MIN re-drapes of P's mean
   material (placement noise only) of the same K draws' best-of-K MSE against each: what the base MSE would be if P
   were right about the specimen, i.e. how much re-draping alone changes a drape. (Until 2026-11-24 the references
   were posterior draws, whose material spread made the floor twice the control drapes' base MSE: 0.031 against
   0.009 in the round-trip test's setting. It was then measured on 6 re-drapes, whose sd of 0.007 gave 0.0105 at one
   seed and 0.0166 at another with the same reference.) An effect whose refit removes less than half of the floor
   changes the drape less than re-draping does (a 4 degree tilt: significant with six images, p 2.6e-6, yet its
   refit removed 0.0027 of a 0.0158 MSE against a control MSE of 0.0105, about 0.26 of the floor; the moderate 0.15
   rad tilt removed 0.0098, 0.93 of it) and is reported, not recommended. gain = (base loss - refit loss) / added
   parameters, loss = the expected pixel data term of the predictive (mean over draws and images), is reported
   beside it: it weighs the draws' spread, which an effect may widen while its best draws come closer (measured:
   best-of-16 MSE 0.0288 -> 0.0189 with a higher loss).
3b. In 3D (with the 3D step test). The base, the comparison and every refit also report their 3D error: the
   best-of-K fold-feature distance (2c's) to the measured meshes (best_of_k_3d), with its re-drape floor (the same
   draws against the re-drapes of P's mean), and each refit its fall in units of that floor (fall_3d_of_redrape).
   A candidate found in 3D only (found_in_3d: its 3D step p the smallest of its tests, its silhouette tests
   alone not significant) is refitted in 3D, such candidates in the order of how much their best 3D step brings the draws' features closer
   to the meshes on average (in the places refit_order gave them: refit_order_3d), not of their 3D p: the line
   search starts at its best 3D step and scores its points by the 3D error, and there are no epochs (the fit's
   epochs follow the pixel loss, which does not see such an effect: a fit on fabric 4's training photo pushed
   high_curvature_bending's log_factor to +0.53, the crests' sign opposite). When no refit is recommended by the
   silhouettes, such a refit is (recommendable_in_3d) when something is significant, it lowers the 3D error by
   MIN_MSE_FALL of the base's, MIN_FALL_OF_REDRAPE of its floor and MIN_3D_GAP_SHARE of the gap between them, and
   the silhouettes' best-of-K MSE stays within ALTERNATIVE_WITHIN of their floor of the base's and the drape
   coefficient error within the measured drape coefficients' standard error of the base's. The candidates
   found in 3D that had no refit and whose steps brought the features closer are named in the verdict with a
   --candidates line (unrefitted_3d): on circle3 within 600 s one or two 3D refits run.

Time budget (seconds, the whole job): the draws and score tests come first (their cost is K drapes with
backward), then the step test (2b: its share, screened when thin); what remains, less the refits' evaluations and
line searches (EVALUATION_OVERHEAD x K forward drapes each, k_eval for the comparison's base and every refit's
end and start, at the drape time measured on the step test's drapes, else on the re-drape floor's, until the first
evaluation is measured: then the measured ones' mean per draw) and a reserve for
the report, is split equally between the refits. The least promising refits are dropped while the time left does not pay one evaluation each; a
refit whose share does not pay for epochs keeps its search's best point when the later refits' single evaluations
leave room for the search, else the step test's best step, evaluated once. Without a budget each refit runs
fit.json default_epochs.
"""
import concurrent.futures
import copy
import hashlib
import html
import json
import itertools
import math
import os
import threading
import time

import numpy as np

from . import fit_effects, fold_geometry, infer, measure, render, sim
from ._native import Cancelled, InputError, SolverError

__all__ = ["diagnose", "score_test", "refit_with_effect", "write_report", "DEFAULT_SAMPLES", "ALPHA", "MAX_REFITS"]

DEFAULT_SAMPLES = 16      # posterior-predictive draws (the score test's sample size)
MIN_SAMPLES = 3           # a covariance over draws needs at least this many
ALPHA = 0.01              # family-wise significance level, Bonferroni over the candidates tested
MAX_REFITS = 3            # refits of the most promising candidates (tilt, offset and camera all shift a drape)
REFIT_P_MAX = 0.05        # once one candidate is significant, the others up to this p are refitted too (module doc, 3.)
MIN_MSE_FALL = 0.05       # a recommended refit lowers the best-of-K MSE by at least this fraction of the base's
MIN_FALL_OF_REDRAPE = 0.5  # ... and by at least this fraction of the re-drape floor (module doc, 3.)
# A candidate without a refit whose p is below this x the threshold is named beside a recommendation (unrefitted)
NEAR_THRESHOLD_FACTOR = 3.0
ALTERNATIVE_WITHIN = MIN_FALL_OF_REDRAPE  # a refit whose MSE is within this x the floor of the recommended's: as good
# a refit fitted in 3D is recommended only when it also closes this share of the 3D error's gap above its re-drape
# floor: on the real fabrics that gap is 20-25 floors, so half a floor is 2 % of it (module doc, 3b; on fabric 2 a
# 0.15 rad tilt closed 6 % of it, 1.3 floors, with the silhouettes unchanged)
MIN_3D_GAP_SHARE = 0.25
SCORE_CLIP_FACTOR = 1.5   # per-draw score norms capped at this x their median (the fit's cap is 3: module doc, 2.)
HARMONIC_ORDERS = 6       # residual harmonics reported: k = 1..6
FLIP_ENUMERATE_MAX = 16  # draws up to which the sign-flip test enumerates all 2^K patterns
FLIP_SAMPLES = 65536      # random sign patterns beyond that
RANK_TOLERANCE = 1e-9     # eigenvalues of the scaled gradient covariance below this x the largest are dropped
MATERIAL_LEARNING_RATE_FACTOR = 0.0  # refits hold the material at P's posterior (module doc)
REFIT_START_LEARNING_RATE_FACTOR = 0.25  # a refit from the step test's step takes steps of this x the fit's (module doc, 3.)
REFIT_AVERAGE_SHARE = 0.5  # ... and reports the mean of this last share of its epochs' effect values
SEARCH_FACTORS = (0.5, 1.0, 1.5, 2.0)  # the refit's line search: multiples of the step it drapes (module doc, 3.)
SEARCH_TURN_RAD = math.pi / 4  # ... and, for an effect that steps two parameters, the step turned by this in their plane
SEARCH_VERTEX_WITHIN = 0.5  # ... whose parabola vertex is kept when it scores within this x the re-drape floor of the
                            # best point (ALTERNATIVE_WITHIN's line: the images do not tell such points apart)
SEARCH_GRID_DRAWS = 2     # a grid search (the registry's search_grid_spacing) scores each point on this many draws,
SEARCH_GRID_FINALISTS = 3  # ... then its best points again on K draws, and starts at the best of those
SEARCH_GRID_CALL_DRAWS = 1.5  # a point's evaluation costs its draws plus about this many drapes (a fresh model)
SEARCH_SEED_OFFSET = 200000  # the search's draws: material and placement seed apart from the base's (module doc, 3.)
REPORT_RESERVE_S = 5.0    # seconds kept back from the refits for the evaluation bookkeeping and the report
SCORE_SIGMA_DC = 0.0      # the score test's data term: pixel term only (see the module doc)
REDRAPE_FLOOR_MIN = 12    # re-drapes the re-drape floor is measured on (at least; module doc, 3.)
PSEUDO_MIN = 4            # predictive silhouettes drawn as the null reference (at least; as many as images)
PSEUDO_SEED_OFFSET = 100000  # their placement seeds: [seed, offset + j, 1], apart from the scored draws' [seed, i, 1]
STEP_REFERENCES_MIN = 24  # predictive silhouettes the step test compares with (at least; 4 per image beyond six)
COMPARISON_SAMPLES_MAX = 64  # the base and the refits are compared on up to this many draws (module doc, 3.) ...
COMPARISON_SHARE = 0.25   # ... as many as this share of the time left when the refits begin pays for, at least K
EVALUATION_OVERHEAD = 1.1  # an evaluation's K drapes (a fresh model each) over K measured forward drapes (step test, else floor)
STEP_FORWARD_SHARE = 0.4  # a forward drape's share of a draw with backward (measured; as the refits' evaluation)
STEP_BUDGET_SHARE = 0.4   # at most this share of the budget left after the score tests goes to the step drapes,
STEP_BUDGET_SHARE_MAX = 0.7  # ... or up to this share when the first leaves fewer than MIN_SAMPLES draws per step
SCREEN_DRAWS = 4          # with a budget that does not pay for every draw on every step: the screen's draws per step,
SCREEN_P_MAX = 0.2        # ... the screen's p below which a candidate is confirmed on fresh draws (module doc, 2b)
SCREEN_BELOW = 0.5        # ... screened when the budget pays for fewer than this share of the draws on every step
SPECIMEN_QUADRATURE = (60, 99)  # the specimen null's chi-square cells: log-spaced per tail, uniform between
STEP_FAMILY_DRAWS = 200000   # the step test's family p: normal draws of the steps' correlation (step_family_p)
STEP_FAMILY_CONFIDENCE = 0.99  # ... whose hit rate enters by this one-sided Clopper-Pearson upper bound
STEP_FAMILY_DRAWN = (1e-5, 0.05)  # ... drawn only where Bonferroni's p lies above the first and the smallest p below
#                                   the second: elsewhere no decision turns on it (Bonferroni's / Sidak's p instead)
# step_direction: the refit starts along the steps' first harmonic where it explains at least this share of their
# statistics' variance (a tilt's four steps: 0.99 at seeds 721 and 751; an offset's eight: 0.37-0.38)
DIRECTION_R2_MIN = 0.8
MESH_NOISE_STREAM = 43    # the 3D step test's vertex noise streams: [seed, this, kind, draw] (MeshFeatures)
STEP_PERMUTATIONS_MAX = 20000  # labellings enumerated up to this count (six images, 12 references: 18564), else drawn
                               # (the relabelling test: the fallback without references, and p_value_permutation)


def second_directions(reg):
    """{effect: {parameter: value}} from the registry's `second_direction`: effects whose primary parameter acts
    along a direction parameter that has no gradient at the off value (a tilt's azimuth at zero angle). The
    primary's score is also taken with the direction parameter at this value (still the base model, the primary
    being off), so that the test sees the effect in every direction; the rollout is the same, so its one adjoint
    gives both (ClothModel.backward's alternatives). Key in the gradients: "tilt.angle_rad@azimuth_rad"."""
    entries = reg.values() if isinstance(reg, dict) else reg
    return {e["name"]: dict(e["second_direction"]) for e in entries if e.get("second_direction")}
FOLD_WORDS = {
    1: "1-fold: the drape hangs further out on one side (offset, tilt, a density or stiffness gradient)",
    2: "2-fold: the drape is longer along one axis (warp-weft anisotropy or shrinkage, camera aspect)",
}


def _progress(progress, stage, message, **extra):
    if progress:
        progress(dict(stage=stage, message=message, **extra))


def score_test(gradients, scale=None, clip=None, nuisance=None, scatter=None, scatter_nuisance=None,
               scatter_groups=None):
    """Score test from per-draw gradients (K, q) of the data term at the off point (see the module doc).
    scale: per-parameter factors (the prior scales: the covariance's rank is judged on comparable units); clip:
    per-draw norms above clip x their median are scaled down to it; nuisance (K,) or (K, r): per-draw gradients of
    nuisance parameters, projected out first (the efficient score with the outer-product estimate of the
    information: g_e - N (N^T N)^-1 N^T g_e), costing r draws of the F test's denominator dof.
    scatter (K, q), scatter_nuisance (K,) or (K, r): per draw, the same gradient of the draw's scatter image (module
    doc, 2.: the measurement's and the reference's own re-drape variability), projected with the same nuisance
    coefficients, scaled and clipped with the same per-draw factors as the draw's score. With it the covariance of
    the mean score is S/K + C_u (S: the scores' covariance over draws), T^2 = gbar^T (that)^+ gbar, and
    p_value is Hotelling's F approximation on K - 1 - r dof (the sign flips see the draws' variability only:
    the measured images' are common to every draw), p_value_draws the draws-only sign-flip p.
    C_u: with scatter_groups (K,) naming which draws share a scatter image, the mean over the pairs (k, l) of one
    group of the symmetrised cross products u_k u_l^T, projected onto the positive semidefinite cone: unbiased for
    Bbar C Bbar^T (k and l independent draws, Bbar the mean adjoint). Without groups, mean(u_k u_k^T), which
    estimates E[B C B^T] >= Bbar C Bbar^T: measured, many times larger, because a pixel's sensitivity to an effect
    changes sign with the draw's fold positions, so the test lost its power (tilt 0.15 rad on 6 drapes: p 0.004).

    p_value is a sign-flip randomisation test of T^2: under "the effect is absent" each draw's score is as likely
    to point either way (a tilt's exactly, the draws' distribution being mirror-symmetric), so T^2 is compared
    with its values under the 2^K sign patterns of the draws (all of them for K <= FLIP_ENUMERATE_MAX, else
    FLIP_SAMPLES seeded random ones). With uncentred moments A = Z^T Z fixed under flips, T^2 is a monotone
    function of |U^T s|^2 (U: Z's left singular vectors, s: the signs), so the test costs one matrix product.
    It needs no Gaussian tails (measured: on 18 tilted and control images it agreed with Hotelling's F,
    p_value_f, within a factor 2 below 0.01). Returns {statistic, rank, p_value (sign flips), p_value_f
    (Hotelling F), p_value_chi2, gradient_mean (after the projection, before scaling and clipping, per
    parameter unit), clipped (draws capped)}."""
    from scipy import stats

    g = np.asarray(gradients, dtype=float)
    if g.ndim != 2 or g.shape[0] < 2:
        raise InputError(f"score_test: expected (draws >= 2, parameters) gradients, got shape {g.shape}")
    k = g.shape[0]
    lost = 0
    if nuisance is not None:
        n = np.asarray(nuisance, dtype=float).reshape(k, -1)
        beta = np.linalg.lstsq(n, g, rcond=None)[0]
        g = g - n @ beta
        lost = np.linalg.matrix_rank(n)
    z = g * (np.ones(g.shape[1]) if scale is None else np.asarray(scale, dtype=float))
    zu = None
    if scatter is not None:
        zu = np.asarray(scatter, dtype=float).reshape(g.shape)
        if nuisance is not None:
            nu = np.asarray(scatter_nuisance, dtype=float).reshape(k, -1)
            zu = zu - nu @ beta
        zu = zu * (np.ones(g.shape[1]) if scale is None else np.asarray(scale, dtype=float))
    factor = np.ones(k)
    if clip:
        # Per-draw gradients of a rollout are exact but heavy-tailed (a fold bifurcating near the end makes one
        # draw's gradient 5-10x the others'; infer.FitJob.clip_threshold): norms are capped at clip x the median.
        norms = np.linalg.norm(z, axis=1)
        cap = float(clip) * float(np.median(norms))
        if cap > 0:
            factor = np.minimum(1.0, cap / np.maximum(norms, 1e-300))
    clipped = int(np.sum(factor < 1.0))
    z = z * factor[:, None]
    mean = z.mean(axis=0)
    cov = np.atleast_2d(np.cov(z, rowvar=False, ddof=1)) / k
    if zu is not None:
        zu = zu * factor[:, None]
        cross = None
        if scatter_groups is not None:
            groups = {}
            for row, grp in enumerate(scatter_groups):
                groups.setdefault(grp, []).append(row)
            terms = [np.outer(zu[a], zu[b]) for rows in groups.values() for i, a in enumerate(rows) for b in rows[i + 1:]]
            if terms:
                c = np.mean(terms, axis=0)
                c = 0.5 * (c + c.T)
                cw, cv = np.linalg.eigh(c)
                cross = (cv * np.maximum(cw, 0.0)) @ cv.T
        cov = cov + (cross if cross is not None else zu.T @ zu / k)
    w, v = np.linalg.eigh(cov)
    top = float(w.max()) if w.size else 0.0
    keep = w > RANK_TOLERANCE * top if top > 0 else np.zeros_like(w, dtype=bool)
    rank = int(keep.sum())
    if rank == 0:
        return {"statistic": 0.0, "rank": 0, "p_value": 1.0, "p_value_f": 1.0, "p_value_chi2": 1.0,
                "p_value_draws": 1.0, "gradient_mean": g.mean(axis=0).tolist(), "clipped": clipped}
    proj = v[:, keep].T @ mean
    t2 = float(np.sum(proj ** 2 / w[keep]))
    p_chi2 = float(stats.chi2.sf(t2, rank))
    dof = k - lost  # draws left after the nuisance projection
    if dof > rank:
        f = t2 * (dof - rank) / (rank * (dof - 1))
        p = float(stats.f.sf(f, rank, dof - rank))
    else:  # cannot happen (rank <= K - 1), kept for safety
        p = p_chi2
    flips = _sign_flip_p(z)
    return {"statistic": t2, "rank": rank, "p_value": p if zu is not None else flips, "p_value_f": p,
            "p_value_chi2": p_chi2, "p_value_draws": flips, "gradient_mean": g.mean(axis=0).tolist(),
            "clipped": clipped}


def _sign_flip_p(z):
    """Sign-flip randomisation p-value of Hotelling's T^2 for the rows of z (see score_test)."""
    k = z.shape[0]
    u, sv, _ = np.linalg.svd(z, full_matrices=False)
    u = u[:, sv > RANK_TOLERANCE * sv.max()] if sv.size and sv.max() > 0 else u[:, :0]
    if k <= FLIP_ENUMERATE_MAX:
        codes = np.arange(2 ** k, dtype=np.int64)
        signs = 1.0 - 2.0 * ((codes[:, None] >> np.arange(k)) & 1)
    else:
        signs = np.random.default_rng(0).choice([-1.0, 1.0], size=(FLIP_SAMPLES, k))
        signs[0] = 1.0
    a = np.sum((signs @ u) ** 2, axis=1)
    observed = float(np.sum(u.sum(axis=0) ** 2))
    return float(np.mean(a >= observed * (1 - 1e-9)))


def _is_switch(entry):
    """An effect whose primary parameter is structural (disk_contact's clamp radius): no score test at its off
    value (CONVENTIONS.md: a genuine switch is judged by its refit alone, and the report says so)."""
    return bool(entry["parameters"][0].get("structural"))


def _check_inputs(preset, images, meshes, candidates, time_budget, samples):
    if not images:
        raise InputError("images: give at least one measured silhouette")
    for path in images:
        if not os.path.isfile(path):
            raise InputError(f"images: {path}: no such file")
    meshes = list(meshes or [])
    if meshes and len(meshes) != len(images):
        raise InputError(f"meshes: {len(meshes)} meshes for {len(images)} images (they pair in order)")
    if preset is None:
        raise InputError("preset: give the preset to diagnose")
    if isinstance(preset, (str, os.PathLike)):
        if not os.path.isfile(preset):
            raise InputError(f"preset: {os.fspath(preset)}: no such file")
        p = infer.load_preset(preset)
    else:
        p = infer.validate_preset(copy.deepcopy(preset))
    reg = fit_effects.registry()
    active = set(p.get("active_effects") or {})
    if candidates is None:
        names = [n for n in reg if n not in active]
    else:
        if isinstance(candidates, str):
            candidates = [c for c in candidates.split(",")]
        names = []
        for c in candidates:
            c = str(c).strip()
            if c not in reg:
                raise InputError(f"candidates: unknown effect {c!r} (registered: {', '.join(reg)})")
            if c in active:
                raise InputError(f"candidates: {c!r} is already active in the preset")
            if c not in names:
                names.append(c)
    if time_budget is not None and not (float(time_budget) > 0):
        raise InputError(f"time_budget: must be > 0 seconds, got {time_budget}")
    k = DEFAULT_SAMPLES if samples is None else int(samples)
    if k < MIN_SAMPLES:
        raise InputError(f"samples: the score test needs at least {MIN_SAMPLES} draws, got {samples}")
    return p, meshes, names, k


def _observations(images):
    obs = [infer._Observation(path, None) for path in images]
    first = obs[0]
    for o in obs[1:]:
        if o.mask.shape != first.mask.shape:
            raise InputError(f"images: {o.path} is {o.mask.shape[1]} x {o.mask.shape[0]} px, {first.path} "
                             f"{first.mask.shape[1]} x {first.mask.shape[0]}: diagnose images of one calibration")
        if abs(o.calibration["px_per_m"] - first.calibration["px_per_m"]) > 0.01 * first.calibration["px_per_m"]:
            raise InputError(f"images: {o.path} has {o.calibration['px_per_m']:.1f} px/m, {first.path} "
                             f"{first.calibration['px_per_m']:.1f} px/m: diagnose images of one calibration")
    return obs


def measured_positions(meshes, model):
    """(positions, None): the measured meshes (OBJ paths) as (V, 3) arrays when every one has the model's topology
    (the dataset's reconstructions are circle3's mesh: diagnose them on --mesh-level 3), else (None, why)."""
    faces = np.asarray(model.faces)
    measured = []
    for path in meshes:
        mesh = sim.read_obj(path)
        x, f = np.asarray(mesh.positions, dtype=float).reshape(-1, 3), np.asarray(mesh.faces)
        if len(x) != model.num_vertices or f.shape != faces.shape or not np.array_equal(f, faces):
            return None, (f"{os.path.basename(os.fspath(path))} has {len(x)} vertices and {len(f)} faces, the "
                          f"model's mesh {model.num_vertices} and {len(faces)}: the 3D comparison and test need the "
                          "measured meshes on the model's topology (the Cusick dataset's reconstructions are "
                          "circle3's: --mesh-level 3)")
        measured.append(x)
    return measured, None


def geometry_3d(meshes, drapes, model, seed=0, noise_m=fold_geometry.RECONSTRUCTION_NOISE_M):
    """The measured meshes (OBJ paths) against the draws' drapes (list of (V, 3)) in 3D: drapelab.fold_geometry's
    comparison per material ring and hinge band with its words, when every measured mesh has the model's topology
    (measured_positions); else {"skipped": why}."""
    measured, why = measured_positions(meshes, model)
    if measured is None:
        return {"skipped": why}
    return fold_geometry.compare(measured, drapes, np.asarray(model.rest_positions), np.asarray(model.bending_edges),
                                 noise_m=noise_m, seed=seed)


def _summary(shapes, observations, camera_cal, sigma_obs, sigma_dc):
    """Base-style metrics of draped draws (hard images) against the observations, and per-image details."""
    ok = [s for s in shapes if s is not None and "error" not in s]
    dcs = np.array([s["dc"] for s in ok])
    nodes = np.array([s["nodes"] for s in ok])
    amps = np.array([s["amplitude"] for s in ok])
    dc_iv = [float(v) for v in np.percentile(dcs, [5, 95])]
    node_iv = [float(v) for v in np.percentile(nodes, [5, 95])]
    amp_iv = [float(v) for v in np.percentile(amps, [5, 95])]
    values, counts = np.unique(nodes, return_counts=True)
    node_mode = int(values[np.argmax(counts)])
    per_image = []
    for o in observations:
        mses = np.array([measure.pixel_mse(s["image"], o.mask) for s in ok])
        best = int(np.argmin(mses))
        loss = float(np.mean([infer.data_term(s["image"], o, sigma_obs, sigma_dc)[0] for s in ok]))  # expected
        per_image.append({"image": o.path, "mse": float(mses[best]), "iou": float(measure.iou(ok[best]["image"], o.mask)),
                          "loss": loss, "best_draw": best,
                          "drape_coefficient": {"observed": o.dc, "predicted_mean": float(dcs.mean()), "interval90": dc_iv},
                          "node_count": {"observed": o.nodes, "predicted_mode": node_mode, "interval90": node_iv},
                          "node_amplitude_m": {"observed": o.amplitude, "predicted_mean": float(amps.mean()),
                                               "interval90": amp_iv}})
    base = {"mse": float(np.mean([e["mse"] for e in per_image])),
            "iou": float(np.mean([e["iou"] for e in per_image])),
            "dc_error": float(np.mean([abs(e["drape_coefficient"]["predicted_mean"] - e["drape_coefficient"]["observed"])
                                       for e in per_image])),
            "node_error": float(np.mean([abs(e["node_count"]["predicted_mode"] - e["node_count"]["observed"])
                                         for e in per_image])),
            "amplitude_error": float(np.mean([abs(e["node_amplitude_m"]["predicted_mean"] - e["node_amplitude_m"]["observed"])
                                              for e in per_image])),
            "loss": float(np.mean([e["loss"] for e in per_image]))}
    return base, per_image, ok


def redrape_change(pseudo):
    """The median pixel MSE between two of P's mean-material re-drapes (placement noise only): how much re-draping
    alone changes a drape; None with fewer than two."""
    pairs = [measure.pixel_mse(a, b) for i, a in enumerate(pseudo or []) for b in pseudo[i + 1:]]
    return float(np.median(pairs)) if pairs else None


def effect_change(shapes, refit_shapes):
    """The median over draws of the pixel MSE between a base draw and the refit's draw of the same index: the same
    material draw and placement noise (both seeded alike), with the fitted effect added, i.e. how much the fitted
    effect changes a drape; None when no pair draped."""
    pairs = [measure.pixel_mse(a["image"], b["image"]) for a, b in zip(shapes, refit_shapes)
             if a is not None and b is not None and "error" not in a and "error" not in b]
    return float(np.median(pairs)) if pairs else None


def strength_of_moderate(entry, values, second=None):
    """The fitted effect's strength in units of its registry moderate strength: the root sum of squares over its
    parameters of (value - off) / moderate, direction parameters (the registry's `second_direction`: a tilt's
    azimuth) left out. A moderate strength changes a drape about 2-3 times as much as re-draping does
    (docs/physics.md)."""
    skip = set((second or {}).get(entry["name"], {}))
    total = 0.0
    for q in entry["parameters"]:
        if q["name"] in skip or q["name"] not in values or not q.get("moderate"):
            continue
        total += ((float(values[q["name"]]) - float(q["off"])) / float(q["moderate"])) ** 2
    return float(np.sqrt(total))


def _redrape_floor(shapes, pseudo):
    """(mean, sd) over P's own predictive silhouettes of the draws' best-of-K MSE against each: the base MSE the
    measurements would get if P were right (module doc, 3.); None without references."""
    ok = [s for s in shapes if s is not None and "error" not in s]
    if not pseudo or not ok:
        return None
    best = [min(measure.pixel_mse(s["image"], q) for s in ok) for q in pseudo]
    return float(np.mean(best)), float(np.std(best, ddof=1)) if len(best) > 1 else 0.0


def stepped_parameters(entry):
    """The parameter names the step test moves for registry entry `entry` (and the refit's line search scales):
    its `step_parameters`, else its primary."""
    return list(entry.get("step_parameters") or [entry["parameters"][0]["name"]])


def alternatives(gaining, redrape):
    """The refits that explain the images about as well as the recommended one (`gaining`: the recommended first,
    then the other refits that lower the error, whether or not they pass the rule themselves): those whose
    best-of-K MSE exceeds the recommended's by less than ALTERNATIVE_WITHIN x the re-drape floor `redrape`, the
    same line a refit's fall must clear to count (module doc, 3.). [{effect, mse, above, of_redrape}]; [] without a
    floor."""
    if not gaining or not redrape:
        return []
    best = gaining[0]["refit"]["mse"]
    out = []
    for e in gaining[1:]:
        above = e["refit"]["mse"] - best
        if above < ALTERNATIVE_WITHIN * redrape:
            out.append({"effect": e["effect"], "mse": e["refit"]["mse"], "above": above,
                        "of_redrape": above / redrape})
    return out


def unrefitted(ranking, threshold, exclude=()):
    """The candidates these images single out, or nearly (p below NEAR_THRESHOLD_FACTOR x the threshold), whose refit
    did not run (no time left, or MAX_REFITS reached): [{effect, p_value, significant}], smallest p first. A
    recommendation names them, so that it is not read as the only effect the images point to (circle3, seed 731's
    prestrain drapes: the softer rim was recommended while prestrain's own p, 1.6x the threshold, and the camera's,
    significant, had no refit; docs/diagnose.md)."""
    out = [{"effect": e["effect"], "p_value": e["p_value"], "significant": e["p_value"] < threshold}
           for e in ranking if e.get("p_value") is not None and e["p_value"] < NEAR_THRESHOLD_FACTOR * threshold
           and e.get("refit") is None and e["effect"] not in exclude]
    return sorted(out, key=lambda u: u["p_value"])


def unrefitted_3d(ranking, threshold, limit=3):
    """The candidates found in 3D (found_in_3d) whose steps brought the draws' fold features closer to the meshes
    on average (change_3d < 0) and that had no refit, the largest change first, at most `limit`: [{effect, change}].
    Only one or two 3D refits fit a 600 s budget on circle3, chosen on the screen's three draws (fabric 2: rest_curvature's
    refit ran, high_curvature_bending's, whose step closes 28 % of the 3D gap, was 4th); the verdict names the rest."""
    out = []
    for e in ranking:
        if e.get("step_3d") is None or e.get("refit") is not None or not found_in_3d(e, threshold):
            continue
        c = change_3d(e)
        if c is not None and c < 0:
            out.append({"effect": e["effect"], "change": c})
    return sorted(out, key=lambda u: u["change"])[:int(limit)]


def unrefitted_3d_words(items):
    """The verdict's sentence on unrefitted_3d's candidates; empty without any."""
    if not items:
        return ""
    names = ",".join(u["effect"] for u in items)
    return (" In 3D the steps of " + ", ".join(f"{u['effect']} ({u['change']:+.2g})" for u in items)
            + " also brought the draws' fold features closer to the meshes on average (their mean distance's change)"
            f" and had no refit; to refit them, diagnose again with --candidates {names}.")


def not_refitted_reason(cancelled, max_refits):
    """Why a candidate the refits would have taken has none (the verdict's words, with or without a
    recommendation)."""
    return ("the diagnosis was cancelled" if cancelled else
            f"no time was left or only {int(max_refits)} are refitted")


def unrefitted_words(items, recommended, reason):
    """The verdict's sentence on `unrefitted` candidates beside a recommendation (`reason`: not_refitted_reason);
    empty without any."""
    if not items:
        return ""
    names = ",".join([recommended] + [u["effect"] for u in items])
    return (". Not refitted (" + reason + "): " + ", ".join(
        f"{u['effect']} (p = {u['p_value']:.2g}, {'significant' if u['significant'] else 'near the threshold'})"
        for u in items) + f"; to compare their refits with it, diagnose again with --candidates {names}")


def alternatives_words(alts, recommended, k):
    """The verdict's sentence on the alternatives (module doc, 3.); empty without any."""
    if not alts:
        return ""
    return (". As good within the re-drape noise: " + ", ".join(
        f"{a['effect']} (best-of-{k} MSE {a['mse']:.4f}, {a['of_redrape']:.2f} of the re-drape floor above)"
        for a in alts) + f": these images do not tell {'it' if len(alts) == 1 else 'them'} from {recommended} "
        f"(differences under {ALTERNATIVE_WITHIN:g} of the floor count as noise)")


def effect_steps(reg, names, second=None, diagonals=True):
    """{effect: [(label, {parameter: value})]}: the finite steps of the step test (module doc, 2b) for the
    candidates that are not switches: each stepped parameter (the registry's `step_parameters`, else the primary)
    at its registry moderate strength, and at minus it when its bounds allow, the effect's other parameters off;
    for an effect with a second direction (the tilt's azimuth) the same again with the direction parameter turned.
    bending_anisotropy steps cos2 and sin2: its 2-fold axis at 0, 90, 45 and 135 degrees; offset dx and dy, and
    (the registry's `step_diagonals`) both at once along the diagonals: eight directions 45 degrees apart
    (`diagonals` False: the four axis steps only, 90 degrees apart; steps_within)."""
    second = second_directions(reg) if second is None else second
    out = {}
    for n in names:
        entry = reg[n]
        if _is_switch(entry):
            continue
        by_name = {q["name"]: q for q in entry["parameters"]}
        stepped = [by_name[q] for q in stepped_parameters(entry)]
        off = {q["name"]: q["off"] for q in entry["parameters"]}
        turns = [({}, "")] + ([(dict(second[n]), "@" + ",".join(f"{q}={v:.3g}" for q, v in second[n].items()))]
                              if n in second else [])
        out[n] = []
        for q in stepped:
            values = [q["moderate"]]
            if q["lower"] <= -abs(q["moderate"]):
                values.append(-q["moderate"])
            out[n] += [(f"{q['name']}={v:+.3g}{tag}", {**off, **turn, q["name"]: v})
                       for turn, tag in turns for v in values]
        if diagonals and entry.get("step_diagonals") and len(stepped) == 2:  # the plane's diagonals, each at the moderate length
            a, b = stepped
            for sa, sb in ((1, 1), (-1, -1), (-1, 1), (1, -1)):
                va, vb = (float(np.clip(sgn * q["moderate"] / math.sqrt(2.0), q["lower"], q["upper"]))
                          for sgn, q in ((sa, a), (sb, b)))
                out[n].append((f"{a['name']}={va:+.3g},{b['name']}={vb:+.3g}", {**off, a["name"]: va, b["name"]: vb}))
    return out


def step_draws(k, left, forward, references, n_steps):
    """How many of the k draws the step test drapes per step, with `left` seconds of the budget, `forward` seconds
    per forward drape and lane, `references` extra reference drapes and n_steps steps: what STEP_BUDGET_SHARE of
    `left` pays for; when that is fewer than MIN_SAMPLES, MIN_SAMPLES if STEP_BUDGET_SHARE_MAX of it pays for them
    (on a fine mesh or a busy machine the usual share may leave the step test too few draws, and then nothing only
    it sees can become significant, and without significance no refit runs); else what that pays for (below
    MIN_SAMPLES: the caller does not run the test)."""
    per_draw = max(forward * n_steps, 1e-9)
    usual, most = (int((share * left - references * forward) / per_draw)
                   for share in (STEP_BUDGET_SHARE, STEP_BUDGET_SHARE_MAX))
    return max(0, min(k, usual if usual >= MIN_SAMPLES else min(MIN_SAMPLES, most)))


def steps_within(steps, axes, score_p, k, left, forward, references):
    """(steps, draws, dropped): the step test's steps cut down to what the budget pays for at MIN_SAMPLES draws,
    when all of them are not (`step_draws` below MIN_SAMPLES; `steps` as effect_steps gives them, `axes` the same
    without the plane diagonals (effect_steps(..., diagonals=False)), `score_p` {effect: score p or None}, the
    other arguments step_draws's). First the plane diagonals go (an effect stepped along its diagonals keeps its
    four axis steps, 90 degrees apart), then whole candidates, the least promising first (largest
    score p; untested ones count as p = 1; ties: the later in the library goes first). `dropped` lists the dropped
    step labels as "effect:label", in the order dropped. Until 2026-11-29 the step test was not run at all when
    the full library's 29 steps did not fit: on circle3 the real fabrics' diagnoses ended with most of their 10
    minutes unused and nothing only the step test sees could become significant (docs/diagnose.md)."""
    steps = {n: list(v) for n, v in steps.items()}
    dropped = []

    def draws():
        return step_draws(k, left, forward, references, sum(len(v) for v in steps.values()))

    if draws() >= MIN_SAMPLES:
        return steps, draws(), dropped
    for n, v in steps.items():  # the diagonals: the steps effect_steps adds to the axis steps
        kept = [label for label, _ in axes[n]]
        dropped += [f"{n}:{label}" for label, _ in v if label not in kept]
        steps[n] = list(axes[n])
    position = {n: i for i, n in enumerate(steps)}
    order = sorted(steps, key=lambda n: (score_p.get(n) if score_p.get(n) is not None else 1.0, -position[n]),
                   reverse=True)
    for n in order:
        if draws() >= MIN_SAMPLES or len(steps) <= 1:
            break
        dropped += [f"{n}:{label}" for label, _ in steps.pop(n)]
    return steps, draws(), dropped


def refits_reserved(score_p, threshold, max_refits):
    """How many refit evaluations a screened step test's confirmation leaves time for (module doc, 2b): one per
    candidate already significant by its score test alone (its combined p, at most twice its score p, below
    `threshold`; `score_p` {effect: p or None}), at least one (the refit of what the confirmation may make
    significant), at most `max_refits`. Until 2026-11-29 it kept `max_refits` evaluations: on circle3 with the whole
    library in 10 minutes that left the confirmation no time on fabrics 3-5, so nothing the score missed could become
    significant, no refit ran, and the reserve went unused (docs/diagnose.md)."""
    if max_refits <= 0:
        return 0
    already = sum(1 for p in score_p.values() if p is not None and 2.0 * p < threshold)
    return int(min(max_refits, max(1, already)))


def confirmation_plan(screen, steps_of, room, forward, fresh, screened, test_s=0.0):
    """The candidates a screened step test confirms (module doc, 2b) and the fresh draws each of their steps gets:
    those whose screen p (`screen` {effect: {p_value, statistic}}) is below SCREEN_P_MAX, most promising first
    (smallest p, then most negative statistic); `room` seconds at `forward` s a drape pay for the draws, at most
    `fresh` of them, and for the confirmed tests' own computation on all their draws, the screened and the fresh
    (`test_s` seconds per draw and step: the screen's step_tests time over its draws and steps); while they pay
    for fewer than the `screened` draws the screen had (the confirmation would not double them), the least
    promising is dropped. `steps_of` {effect: its step count}. Returns (names, draws)."""
    names = sorted((n for n, st in screen.items() if st["p_value"] < SCREEN_P_MAX),
                   key=lambda n: (screen[n]["p_value"], screen[n]["statistic"]))
    test_s = max(0.0, float(test_s))
    while names:
        n_steps = sum(steps_of[n] for n in names)
        per_draw = max(forward + test_s, 1e-9) * n_steps
        m = min(int(fresh), int(max(0.0, room - test_s * n_steps * screened) / per_draw))
        if m >= max(1, min(int(screened), int(fresh))):
            return names, m
        names = names[:-1]
    return [], 0


def step_permutation_test(deltas, n, max_permutations=None, seed=0):
    """The step test's p-value (module doc, 2b). `deltas` [S, N]: per step of one effect, per image (the first `n`
    measured, the other N - n P's own predictive references) the change the step makes to the draws' mean pixel MSE
    against that image. Per step the statistic is its mean over the measured images minus its mean over the
    references (negative: the step brings the draws closer to the measurements than to P's own drapes); the
    effect's statistic is the smallest over its steps. Under "P is right" measured and reference images are
    exchangeable, so p is the share of the C(N, n) ways to label n of the N images "measured" (all enumerated up to
    `max_permutations`, else that many drawn, the observed labelling among them) whose smallest statistic is at
    most the observed one: the choice of step is part of the statistic. Returns (step index, statistic, p)."""
    d = np.atleast_2d(np.asarray(deltas, dtype=float))
    s_count, total = d.shape
    if not 0 < n < total:
        raise ValueError(f"step_permutation_test: {n} measured of {total} images")
    limit = int(max_permutations or STEP_PERMUTATIONS_MAX)
    if math.comb(total, n) <= limit:
        labels = np.zeros((math.comb(total, n), total))
        for row, chosen in enumerate(itertools.combinations(range(total), n)):
            labels[row, list(chosen)] = 1.0
    else:
        rng = np.random.default_rng(seed)
        labels = np.zeros((limit, total))
        labels[0, :n] = 1.0
        chosen = np.argsort(rng.random((limit - 1, total)), axis=1)[:, :n]  # n of the images, uniformly, per row
        np.put_along_axis(labels[1:], chosen, 1.0, axis=1)
    stats = labels @ d.T / n - (1.0 - labels) @ d.T / (total - n)      # [permutations, steps]
    observed = d[:, :n].mean(axis=1) - d[:, n:].mean(axis=1)
    best = int(np.argmin(observed))
    smallest = stats.min(axis=1)
    p = float(np.mean(smallest <= observed[best] + 1e-12 * max(1.0, abs(observed[best]))))
    return best, float(observed[best]), p


def _chi2_nodes(dof):
    """Quadrature of a chi-square variable with `dof` degrees of freedom: (values, weights) at the midpoints in
    probability of SPECIMEN_QUADRATURE's cells (fine in both tails, where the variances' uncertainty decides small
    p-values), the weights summing to 1 - 2e-12."""
    from scipy import stats

    edges = np.unique(np.concatenate([np.logspace(-12, -2, SPECIMEN_QUADRATURE[0]),
                                      np.linspace(0.01, 0.99, SPECIMEN_QUADRATURE[1]),
                                      1.0 - np.logspace(-2, -12, SPECIMEN_QUADRATURE[0])]))
    return stats.chi2.ppf(0.5 * (edges[1:] + edges[:-1]), dof), np.diff(edges)


def step_specimen_test(deltas, n, n_references, n_redrapes=0):
    """The step test's p-value against the specimen null (module doc, 2b). `deltas` [S, N] as for
    step_permutation_test, its columns the n measured images, then `n_references` posterior-predictive references
    (each a specimen of its own drawn from P), then `n_redrapes` re-drapes of P's mean material (placement only).
    Under "P is right" the measured images are n re-drapes of ONE specimen drawn from P, so their mean change m has
    the variance B + W / n about the references' mean r (B: the variance between specimens of a specimen's
    expected change, W: the variance between re-drapes of one specimen), not (B + W) / n as if every image were a
    specimen of its own (the relabelling test's null, too narrow where P is uncertain), nor W / n (re-drapes of P's
    mean alone, where every step towards the specimen passes). The references' variance v_r estimates B + W on
    J - 1 dof, the re-drapes' and measured images' pooled spread v_w estimates W; both are uncertain, and a B
    estimated as their difference makes small p-values far too small (measured: 7x at 0.001 where B = W). So p is
    the probability of a change at most m - r averaged over the two variances' posteriors (scaled inverse
    chi-square, B + W at least W), by quadrature: Phi((m - r) / sqrt(B + W / n + (B + W) / J)). Measured on
    simulated Gaussian nulls (5000-20000 each): rejection rates at 0.001 of 0.0009-0.0018 where B >= W, fewer
    where B is smaller (conservative). The effect's p is its smallest step's corrected for the choice among its S
    steps (the choice of step is part of the statistic): step_family_p, with the steps' correlation from the
    plug-in covariance of their statistics (neighbouring steps, an offset's eight directions, move the draws
    alike, and Sidak over S would treat them as S chances). Returns (step index, statistic m - r, p, z: the same
    change over the plug-in sd sqrt(max(v_r - v_w, 0) + v_w / n + v_r / J))."""
    from scipy import stats

    d = np.atleast_2d(np.asarray(deltas, dtype=float))
    s_count, total = d.shape
    j, f = int(n_references), int(n_redrapes)
    if n < 1 or j < 3 or f < 0 or n + j + f != total:
        raise ValueError(f"step_specimen_test: {n} measured, {j} references and {f} re-drapes of {total} images")
    m, r, q = d[:, :n], d[:, n:n + j], d[:, n + j:]
    observed = m.mean(axis=1) - r.mean(axis=1)
    # the steps' covariances over the references (B + W) and pooled over the re-drapes and measured images (W);
    # their diagonals are each step's variances, the whole matrices correlate the steps (step_family_p)
    cov_r = np.atleast_2d(np.cov(r, ddof=1))
    within_groups = [g for g in (q, m) if g.shape[1] >= 2]
    nu_w = sum(g.shape[1] - 1 for g in within_groups)
    cov_w = (sum(np.atleast_2d(np.cov(g, ddof=1)) * (g.shape[1] - 1) for g in within_groups) / nu_w
             if within_groups else None)
    v_r = np.diag(cov_r)
    v_w = None if cov_w is None else np.diag(cov_w)
    x_r, w_r = _chi2_nodes(j - 1)
    if v_w is not None:
        x_w, w_w = _chi2_nodes(nu_w)
    p_steps, z = np.ones(s_count), np.zeros(s_count)
    for s in range(s_count):
        total_var = (j - 1) * v_r[s] / x_r                      # B + W, per node
        if v_w is None:  # one image, no re-drapes: nothing separates B from W; the widest null, B + W
            var, weight = total_var * (1.0 + 1.0 / j), w_r
            plug = v_r[s] * (1.0 + 1.0 / j)
        else:
            within = nu_w * v_w[s] / x_w                          # W, per node
            tv, wv = np.maximum(total_var[:, None], within[None, :]), within[None, :]
            var = (tv - wv) + wv / n + tv / j
            weight = w_r[:, None] * w_w[None, :]
            plug = max(v_r[s] - v_w[s], 0.0) + v_w[s] / n + v_r[s] / j
        if not np.all(var > 0):  # every image changed alike (no spread at all): no evidence either way
            continue
        p_steps[s] = float(np.sum(weight * stats.norm.cdf(observed[s] / np.sqrt(var))) / np.sum(weight))
        z[s] = observed[s] / math.sqrt(plug)
    best = int(np.argmin(p_steps))
    if cov_w is None:
        cov = cov_r * (1.0 + 1.0 / j)
    else:
        lam, vec = np.linalg.eigh(cov_r - cov_w)
        cov = (vec * np.maximum(lam, 0.0)) @ vec.T + cov_w / n + cov_r / j
    p = step_family_p(p_steps, cov)
    return best, float(observed[best]), min(1.0, max(p, np.finfo(float).tiny)), float(z[best])


def step_family_p(p_steps, cov, draws=None, seed=0):
    """The p-value of the smallest of one effect's step p's `p_steps` [S] (each against its own null), corrected for
    the choice among the S steps: P(min_s U_s <= min p) when the steps' statistics are jointly normal with the
    covariance `cov` [S, S] (their plug-in covariance), U_s = Phi(Z_s), Z ~ N(0, corr(cov)): the share of
    `draws` (STEP_FAMILY_DRAWS) such draws whose smallest U is at most min p, taken at its one-sided
    STEP_FAMILY_CONFIDENCE Clopper-Pearson upper bound, and never above Bonferroni's S min p. Independent steps
    give Sidak's 1 - (1 - p)^S, steps that move the draws alike fewer chances (identical ones: p itself), opposite
    ones (+- a parameter: one helps where the other hurts) up to S p. A step without spread (p 1, variance 0) is
    taken as independent of the others. Drawn only between STEP_FAMILY_DRAWN's bounds (0.15 s an effect), where
    a decision can turn on it; below, Bonferroni's p; above, Sidak's."""
    from scipy import stats

    p_steps = np.asarray(p_steps, dtype=float)
    s_count = p_steps.size
    p_min = float(np.min(p_steps))
    bonferroni = min(1.0, s_count * p_min)
    if s_count == 1 or p_min >= 1.0:
        return min(1.0, p_min)
    if bonferroni <= STEP_FAMILY_DRAWN[0]:
        return bonferroni
    if p_min >= STEP_FAMILY_DRAWN[1]:
        return float(-np.expm1(s_count * np.log1p(-p_min)))
    c = np.array(cov, dtype=float).reshape(s_count, s_count)
    sd = np.sqrt(np.clip(np.diag(c), 0.0, None))
    ok = sd > 0
    corr = np.eye(s_count)
    corr[np.ix_(ok, ok)] = c[np.ix_(ok, ok)] / np.outer(sd[ok], sd[ok])
    lam, vec = np.linalg.eigh(0.5 * (corr + corr.T))
    root = vec * np.sqrt(np.maximum(lam, 0.0))
    n_draws = int(draws or STEP_FAMILY_DRAWS)
    z = np.random.default_rng(seed).standard_normal((n_draws, s_count)) @ root.T
    hits = int(np.count_nonzero(z.min(axis=1) <= stats.norm.ppf(p_min)))
    upper = 1.0 if hits >= n_draws else float(stats.beta.ppf(STEP_FAMILY_CONFIDENCE, hits + 1, n_draws - hits))
    return float(max(p_min, min(bonferroni, upper)))


def _in_lanes(run, lanes):
    """run(lane) for lane in range(lanes), on threads when there are several (the diagnosis' drapes); an exception in
    a lane (Cancelled, SolverError) is raised here."""
    if lanes == 1:
        run(0)
        return
    with concurrent.futures.ThreadPoolExecutor(lanes) as pool:
        for f in [pool.submit(run, lane) for lane in range(lanes)]:
            f.result()



class _ForwardModels:
    """Per lane, the lightest model a forward drape needs: P's own effects and, for a step, the one effect stepped.
    The candidates at their off values are bit-for-bit no-ops (tests/native/physics/test_effects.cpp), so these
    drape as the scoring model with every candidate on does (bit for bit with none stepped; with a step on, up to
    the round-off of summing the terms in another order, 1e-15 m), and faster (on circle3 that model's forward
    costs 10-25 % more, the candidates' terms evaluated at zero). Models are built when first asked (0.1 s each)."""

    def __init__(self, mesh, density, p_active, px_per_m, lanes):
        self._args = (mesh, density, dict(p_active), px_per_m)
        self._models = {}
        self._lock = threading.Lock()
        self.plain = [self.get(lane) for lane in range(lanes)]

    def get(self, lane, effect=None, off=None):
        """Lane `lane`'s model with P's effects and `effect` on at `off` (its off values {param: value})."""
        key = (lane, effect)
        with self._lock:
            if key not in self._models:
                mesh, density, p_active, px_per_m = self._args
                effects = dict(p_active, **({effect: dict(off or {})} if effect else {}))
                self._models[key] = infer.sim.ClothModel(mesh, heterogeneous=True, density=density, effects=effects,
                                                         px_per_m=px_per_m)
            return self._models[key]


def _forward_silhouette(m, p, v0, pred, config, cancel_event, with_positions=False):
    """The hard silhouette of one forward drape (no record), or None when the drape fails; Cancelled passes.
    `with_positions`: (silhouette, positions (V, 3)), (None, None) when the drape fails."""
    try:
        x = m.simulate(p, mode="dynamic", record=False, velocities0=v0, cancel_event=cancel_event,
                       **config["dynamic"])
    except SolverError:
        return (None, None) if with_positions else None
    image = infer._hard_image(pred.camera, infer._observed(m, x, p), m.faces)
    return (image, np.asarray(x, dtype=float).reshape(-1, 3)) if with_positions else image


def step_tasks(steps, n_used):
    """The step drapes' order: [(effect, step index, values, draw index)], draw after draw, every step of a draw
    before the next draw's, so that the draws draped by a deadline are complete (_step_drapes)."""
    jobs = [(n, si, values) for n, st in steps.items() for si, (_, values) in enumerate(st)]
    return [(n, si, values, u) for u in range(n_used) for n, si, values in jobs]


def complete_draws(images, n_used):
    """How many of the leading draws have an attempted drape on every step: the first u whose images (the step
    drapes {key: [image, None (the drape failed), or the marker False (not draped)] per draw}) hold the marker
    ends the count."""
    for u in range(n_used):
        if any(v[u] is False for v in images.values()):
            return u
    return n_used


def _step_drapes(pred, drawn, steps, used, config, lanes, progress, cancel_event, deadline=None, positions=None):
    """Hard images of the scored draws `used` (the same material draws, P's effect draws and placement noise) with
    each step's effect switched on: {(effect, step index): [image or None per used draw]}. Forward drapes only, each
    on a model with P's effects and the stepped one (drawn["light"], _ForwardModels).
    With a `deadline` (time.monotonic() seconds) no drape starts after it; the draws are draped one after the other
    (step_tasks), and a draw not draped on every step is left out: its images are dropped, so the lists are as long
    as the complete draws (complete_draws). A budget is a promise: the screen's confirmation runs to its deadline
    and not past it (measured on circle3 before it: 16-43 s past its plan, the refit evaluation it had reserved
    left unpaid, docs/diagnose.md). `positions` (a dict): filled like the result with the drapes' positions (None
    where a drape failed), for the 3D step test."""
    tasks = step_tasks(steps, len(used))
    out = {(n, si): [False] * len(used) for n, st in steps.items() for si in range(len(st))}  # False: not draped
    xs = {key: [None] * len(used) for key in out}
    done = [0]
    cursor = [0]  # the next task, shared by the lanes: draws complete in order
    lock = threading.Lock()
    t0 = time.monotonic()

    def run(lane):
        while True:
            if cancel_event is not None and cancel_event.is_set():
                return
            if deadline is not None and time.monotonic() >= deadline:
                return
            with lock:
                if cursor[0] >= len(tasks):
                    return
                n, si, values, u = tasks[cursor[0]]
                cursor[0] += 1
            i = used[u]
            base = drawn["effects"][i] if drawn["effects"] else {}
            m = drawn["light"].get(lane, n, drawn["offs"][n])
            p = m.parameters(stretch=pred.stretch, bend=drawn["bend"][i], effects={**base, n: values})
            try:
                got = _forward_silhouette(m, p, drawn["velocities"][i], pred, config, cancel_event,
                                          with_positions=positions is not None)
            except Cancelled:
                return
            out[(n, si)][u], xs[(n, si)][u] = got if positions is not None else (got, None)
            with lock:
                done[0] += 1
                if done[0] % max(1, len(tasks) // 10) == 0 or done[0] == len(tasks):
                    _progress(progress, "steps", f"step drapes {done[0]}/{len(tasks)} ({time.monotonic() - t0:.1f} s)",
                              done=done[0], total=len(tasks))

    _in_lanes(run, lanes)
    complete = complete_draws(out, len(used))
    if positions is not None:
        positions.update({key: v[:complete] for key, v in xs.items()})
    return {key: v[:complete] for key, v in out.items()}


def step_tests(base_images, step_images, steps, observed, references, redrapes=(), distance=None):
    """{effect: {statistic, p_value, z, p_value_permutation, step, best_of_k_fall, per_step}} from the step drapes (module
    doc, 2b): per step, the change of the draws' mean pixel MSE against every measured, reference and re-drape image
    (draws that failed with the step are left out on both sides), then step_specimen_test (p_value; with fewer than
    three references, step_permutation_test) and, for comparison, step_permutation_test on the measured images and
    references (p_value_permutation). best_of_k_fall is the measured images' mean best-of-K MSE fall the best step
    makes (positive: closer); per_step, every step's statistic and its `change` (the draws' mean distance to the
    measured images, its change alone: the statistic less the references' change). `distance(a, q)`: what is compared instead of the pixel MSE (the 3D step test's
    feature distance, step_tests_3d; the "images" are then whatever it takes)."""
    distance = distance or measure.pixel_mse
    images = list(observed) + list(references) + list(redrapes)
    n, j = len(observed), len(references)
    base = np.array([[distance(b, q) for q in images] if b is not None else [np.nan] * len(images)
                     for b in base_images])
    out = {}
    for name, st in steps.items():
        deltas, falls, failed = [], [], set()
        for si in range(len(st)):
            imgs = step_images[(name, si)]
            e = np.array([[distance(a, q) for q in images] if a is not None else [np.nan] * len(images)
                          for a in imgs])
            both = ~np.isnan(e[:, 0]) & ~np.isnan(base[:, 0])
            if both.sum() < MIN_SAMPLES:
                deltas.append(np.zeros(len(images)))
                falls.append(0.0)
                failed.add(si)
                continue
            deltas.append(np.mean(e[both] - base[both], axis=0))
            falls.append(float(np.mean(np.min(base[both, :n], axis=0) - np.min(e[both, :n], axis=0))))
        deltas = np.asarray(deltas)
        # per step: the change against the measured images less that against P's own drapes (the statistic the
        # tests take per step; step_direction reads a direction from them)
        per_step = deltas[:, :n].mean(axis=1) - (deltas[:, n:n + j].mean(axis=1) if j else 0.0)
        change = deltas[:, :n].mean(axis=1)  # the draws' mean distance to the measured images, its change alone
        best, stat, p_perm = step_permutation_test(deltas[:, :n + j], n)
        p, z = p_perm, None  # fewer than three references (their drapes failed): the relabelling test's
        if j >= 3:
            best, stat, p, z = step_specimen_test(deltas, n, j, len(images) - n - j)
        out[name] = {"statistic": stat, "p_value": p, "z": z, "p_value_permutation": p_perm,
                     "step": st[best][0], "values": dict(st[best][1]), "best_of_k_fall": falls[best],
                     "per_step": [{"step": label, "values": dict(values),
                                   "statistic": None if si in failed else float(x),
                                   "change": None if si in failed else float(c)}
                                  for si, ((label, values), x, c) in enumerate(zip(st, per_step, change))]}
    return out


class MeshFeatures:
    """The 3D step test's view of drapes (module doc, 2c): fold_geometry.features of a drape on the model's
    specimen (rest, bending edges), the simulated drapes' hinge angles taken with `noise_m` of vertex noise (the
    measured meshes' own reconstruction noise: they carry theirs), drawn per drape from a stream fixed by the
    drape's `key`, so the features do not depend on the threads' order (a step drape takes its draw's key:
    common random numbers)."""

    def __init__(self, rest, edges, noise_m, seed):
        self.rest, self.edges = np.asarray(rest, dtype=float), np.asarray(edges)
        self.noise_m, self.seed = float(noise_m), int(seed)

    def measured(self, x):
        return fold_geometry.features(x, self.rest, self.edges)

    def simulated(self, x, key):
        """`key`: a tuple of whole numbers naming the drape (its kind, draw and step)."""
        if x is None:
            return None
        rng = np.random.default_rng([self.seed, MESH_NOISE_STREAM, *(int(k) for k in key)])
        return fold_geometry.features(x, self.rest, self.edges, self.noise_m, rng)


def feature_scale(measured, references):
    """(scale, kept): per 3D feature the references' sd (P's own predictive drapes: how much the feature varies
    where P is right), and which features the 3D step test compares: measured on every measured mesh and
    reference drape (a coarse mesh leaves rings unmeasured) and varying over the references."""
    m, r = np.atleast_2d(np.asarray(measured, dtype=float)), np.atleast_2d(np.asarray(references, dtype=float))
    kept = ~np.isnan(m).any(axis=0) & ~np.isnan(r).any(axis=0)
    scale = np.ones(m.shape[1])
    if len(r) >= 2:
        scale[kept] = np.std(r[:, kept], axis=0, ddof=1)
    kept &= scale > 0
    return np.where(kept, scale, 1.0), kept


def feature_distance(scale, kept):
    """distance(a, q) of two drapes' fold features: the mean squared difference of the `kept` features, each over
    its `scale` (feature_scale); NaN when one of them is missing."""
    def distance(a, q):
        d = (np.asarray(a)[kept] - np.asarray(q)[kept]) / scale[kept]
        return float(np.mean(d * d)) if not np.isnan(d).any() else np.nan
    return distance


def best_of_k_3d(draw_features, targets, distance):
    """The 3D analogue of the best-of-K MSE: the mean over the `targets` (measured meshes' or re-drapes' features) of
    the smallest distance from any of the draws' features (None: a failed drape, left out); None without either."""
    drawn = [f for f in draw_features if f is not None]
    if not drawn or not targets:
        return None
    return float(np.mean([min(distance(f, t) for f in drawn) for t in targets]))


def step_tests_3d(base_features, step_features, steps, measured, references, redrapes=(), scale=None):
    """The 3D step test (module doc, 2c): step_tests with each drape's fold features (fold_geometry.features:
    crest and hoop hinge angles per band, height and fold amplitude per ring) in place of its silhouette and the
    mean squared difference of the features, each over the references' sd, in place of the pixel MSE. Per step
    the statistic is then the step's mean feature change projected on how the measured meshes differ from P's own
    drapes (the quadratic's terms in the draw alone cancel between measured and references), and its p is the
    specimen null's as in 2D. `scale`: feature_scale's (scale, kept) of these measured meshes, references and
    re-drapes, when the caller has it. Returns step_tests' dict, plus "features" (the compared features' names)."""
    scale, kept = scale or feature_scale(measured, list(references) + list(redrapes))
    if not kept.any():
        return {}
    distance = feature_distance(scale, kept)
    out = step_tests(base_features, step_features, steps, measured, references, redrapes, distance=distance)
    names = [nm for nm, k in zip(fold_geometry.feature_names(), kept) if k]
    for st in out.values():
        st["features"] = names
    return out


def found_in_3d(entry, threshold):
    """Whether a ranking entry was found in 3D only: its 3D step test's p is the smallest of its tests' and its
    silhouette tests alone (score and step, combined_p) are not below `threshold`. Its refit is then a line search
    scored by the 3D error, from the 3D test's best step, with no epochs (the fit's epochs see the silhouettes
    only; module doc, 3b); an effect the silhouettes show is refitted on them as before."""
    st3 = entry.get("step_3d")
    others = [q for q in (entry.get("p_value_score"), (entry.get("step") or {}).get("p_value")) if q is not None]
    return (st3 is not None and (not others or st3["p_value"] < min(others))
            and (not others or combined_p(*others) >= threshold))


def dc_standard_error(per_image):
    """The measured drape coefficients' standard error (their sd over sqrt(n)) from diagnosis per_image entries;
    None with fewer than two images."""
    dc = [float(x["drape_coefficient"]["observed"]) for x in per_image or []
          if (x.get("drape_coefficient") or {}).get("observed") is not None]
    return float(np.std(dc, ddof=1) / math.sqrt(len(dc))) if len(dc) >= 2 else None


def recommendable_in_3d(ranking, base_3d, floor_3d, base_mse, redrape, any_significant, base_dc=None,
                        dc_within=None):
    """The refits fitted in 3D that may be recommended (module doc, 3b), largest 3D fall first: some candidate is
    significant, the refit lowers the 3D error `base_3d` by at least MIN_MSE_FALL of it, MIN_FALL_OF_REDRAPE of its
    re-drape floor `floor_3d` (fall_3d_of_redrape) and MIN_3D_GAP_SHARE of the gap between them, and its
    silhouettes' best-of-K MSE is at most ALTERNATIVE_WITHIN x their re-drape floor `redrape` above the base's
    `base_mse` (the outline as good as the base's), and its drape coefficient error at most `dc_within` (the
    measured drape coefficients' standard error, dc_standard_error) above the base's `base_dc` (unchecked when
    either is None). The last since fabric 1: high_curvature_bending's refit brought the crests closer (3D error
    5.48 -> 3.82) with the MSE within half a floor, but its drape coefficient error rose 0.027 -> 0.069 (standard
    error 0.007), and on the fabric's unseen photos 0.052 -> 0.080 with the fold-depth bias +1.6 -> +2.5 mm."""
    if not (any_significant and base_3d and floor_3d and base_mse is not None and redrape):
        return []
    ok = [e for e in ranking if (e.get("refit") or {}).get("fitted_in") == "3d"
          and e.get("fall_3d_of_redrape") is not None and e["fall_3d_of_redrape"] >= MIN_FALL_OF_REDRAPE
          and (base_3d - e["refit"]["error_3d"]) / base_3d >= MIN_MSE_FALL
          and base_3d - e["refit"]["error_3d"] >= MIN_3D_GAP_SHARE * (base_3d - floor_3d)
          and e["refit"]["mse"] <= base_mse + ALTERNATIVE_WITHIN * redrape
          and (base_dc is None or dc_within is None or e["refit"].get("dc_error") is None
               or e["refit"]["dc_error"] <= base_dc + dc_within)]
    return sorted(ok, key=lambda e: -e["fall_3d_of_redrape"])


def why_in_3d(best, ranking, threshold):
    """Words for why a refit fitted in 3D (`best`, a ranking entry) is recommended: its own significance, or, when
    its p is above `threshold`, that it explains best the difference some other candidate's test found (fabric 2:
    high_curvature_bending's p 0.0019 against a threshold of 0.00091, bending_anisotropy's 3.8e-7)."""
    if best["p_value"] is not None and best["p_value"] < threshold:
        return f"significant (p = {best['p_value']:.2g} < {threshold:.2g}, by its 3D step test)"
    found = sorted((e for e in ranking if e["p_value"] is not None and e["p_value"] < threshold),
                   key=lambda e: e["p_value"])
    by = f", {found[0]['effect']}'s p = {found[0]['p_value']:.2g} < {threshold:.2g}" if found else ""
    own = f"its own p = {best['p_value']:.2g}" if best["p_value"] is not None else "untested"
    return f"the refit that explains the significant difference in 3D best ({own}{by})"


def combined_p(*p_values):
    """A candidate's p from its tests' (score, step, 3D step; None: not run): Bonferroni over the tests run,
    min(1, m min p)."""
    ps = [float(q) for q in p_values if q is not None]
    return min(1.0, len(ps) * min(ps)) if ps else None


def step_direction(entry, second, per_step):
    """The refit's start direction from all of a directional effect's steps (module doc, 3.), or None. `entry`: the
    registry entry; `second`: its second_direction ({parameter: value}) or None; `per_step`: its step test's steps
    [{values, statistic}] (step_tests' per_step; statistic None where a step's draws failed). A directional effect is one
    whose steps lie in a plane: two step_parameters (an offset's dx, dy; bending_anisotropy's cos2, sin2), or a
    primary turned by a second direction (a tilt's angle at azimuth 0 and 90 degrees, signed: four directions).
    To second order the change a step s makes to the draws' MSE against the measurements is s'Hs - 2 s'Ht for an
    effect t in the data, so over steps of one length around the circle its first harmonic points away from Ht:
    the least-squares fit statistic ~ c + g . u(phi) over the steps' unit directions u gives the direction -g,
    which weighs every step (the best single step is off by up to half the steps' spacing: 45 degrees for a tilt).
    The refit starts there only where the first harmonic explains the steps (`used`: r2 >= DIRECTION_R2_MIN): a
    tilt's four steps fit it closely (r2 0.99 at seeds 721 and 751), an offset's eight often do not (r2 0.4: its
    step signature is mostly its folds rearranging, and there the harmonic pointed 54 degrees off where the best
    step was 32 degrees off), and then the best step stays the start. Returns {"values": the effect's values at
    the steps' mean length along -g, "direction_rad": its angle in the plane, "harmonic": |g|, "residual": the
    fit's rms residual, "r2": the share of the steps' variance it explains, "used"} or None (fewer than three
    usable steps, or steps that do not span the plane)."""
    params = {q["name"]: q for q in entry["parameters"]}
    stepped = stepped_parameters(entry)
    if len(stepped) == 2:
        a, b = stepped

        def vec(v):
            return float(v[a]) - float(params[a]["off"]), float(v[b]) - float(params[b]["off"])
    elif second and len(second) == 1 and len(stepped) == 1:
        prim, turn = stepped[0], next(iter(second))

        def vec(v):
            x, phi = float(v[prim]) - float(params[prim]["off"]), float(v[turn])
            return x * math.cos(phi), x * math.sin(phi)
    else:
        return None
    rows = [(vec(x["values"]), float(x["statistic"])) for x in per_step
            if x["statistic"] is not None and math.isfinite(x["statistic"])]
    rows = [(xy, x) for xy, x in rows if math.hypot(*xy) > 0]
    if len(rows) < 3:
        return None
    lengths = np.array([math.hypot(*xy) for xy, _ in rows])
    u = np.array([xy for xy, _ in rows]) / lengths[:, None]
    design = np.column_stack([np.ones(len(rows)), u])
    if np.linalg.matrix_rank(design) < 3:
        return None
    y = np.array([x for _, x in rows])
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    g = coef[1:]
    if not np.all(np.isfinite(g)) or np.hypot(*g) == 0:
        return None
    phi = math.atan2(-g[1], -g[0])
    length = float(np.mean(lengths))
    off = {q: float(params[q]["off"]) for q in params}
    if len(stepped) == 2:
        values = {**off, a: params[a]["off"] + length * math.cos(phi), b: params[b]["off"] + length * math.sin(phi)}
    else:
        values = {**off, prim: params[prim]["off"] + length, turn: phi}
    values = {q: float(np.clip(v, params[q]["lower"], params[q]["upper"])) for q, v in values.items()}
    residual = float(np.sqrt(np.mean((design @ coef - y) ** 2)))
    spread = float(np.mean((y - y.mean()) ** 2))
    r2 = 1.0 - residual ** 2 / spread if spread > 0 else 0.0
    return {"values": values, "direction_rad": phi, "harmonic": float(np.hypot(*g)), "residual": residual,
            "r2": r2, "used": bool(r2 >= DIRECTION_R2_MIN)}


def refit_start(st, by="statistic"):
    """(values, how, label) where a refit starts from its effect's step test `st` (step_tests' entry, with its
    `direction` where step_direction gave one), or (None, None, None) when no step brought the draws closer to the
    measurements (every step's statistic >= 0). how: "harmonic" (a directional effect whose steps follow a first
    harmonic: along it; label None) or "statistic" (the step with the most negative statistic, label its step). The start is a point estimate of
    where the data lie, so it goes by the change itself, not by the step test's p (which also weighs each step's
    spread and picks the reported step): at seed 761 a prestrain of +0.031 was stepped at +-0.03, the +0.03 step
    changed the draws by -0.043 and the -0.03 one by -0.039 with the smaller p, and the refit that started at -0.03
    stayed on the wrong side (docs/diagnose.md). Without per-step statistics: the reported step when its statistic
    is negative. by="change": the step with the most negative `change` instead, and no harmonic (a refit found in
    3D: refit_order_3d, which chose it by that step)."""
    per = [(x[by], i) for i, x in enumerate(st.get("per_step") or []) if x.get(by) is not None]
    if not per:
        return ((dict(st["values"]), "statistic", st["step"]) if by == "statistic" and st["statistic"] < 0
                else (None, None, None))
    lowest, i = min(per)
    if lowest >= 0:
        return None, None, None
    direction = st.get("direction") or {}
    if by == "statistic" and direction.get("used"):
        return dict(direction["values"]), "harmonic", None
    return dict(st["per_step"][i]["values"]), by, st["per_step"][i]["step"]


def _outside_words(entry):
    """Sentences for the measured values outside the predictive 90 % interval."""
    out = []
    for key, what, unit, factor in (("drape_coefficient", "drape coefficient", "", 1.0),
                                    ("node_count", "node count", "", 1.0),
                                    ("node_amplitude_m", "node amplitude (fold depth)", " mm", 1000.0)):
        e = entry[key]
        lo, hi = e["interval90"]
        v = e["observed"]
        if v < lo or v > hi:
            side = "above" if v > hi else "below"
            out.append(f"The measured {what} {factor * v:.3g}{unit} lies {side} the model's 90 % predictive interval "
                       f"[{factor * lo:.3g}, {factor * hi:.3g}]{unit}.")
    return out


def _signature(obs, ok, best, calibration):
    """r(theta) of the measurement and of the best draw, the residual and its harmonics k = 1..6 against the
    re-drape floor (median harmonics of best draw minus each other draw)."""
    r_obs = np.asarray(measure.r_theta(obs.mask, calibration), dtype=float)
    curves = [np.asarray(measure.r_theta(s["image"], calibration), dtype=float) for s in ok]
    r_best = curves[best]
    residual = r_obs - r_best
    n = HARMONIC_ORDERS + 1
    amp = np.asarray(measure.harmonics(residual, n), dtype=float)[1:n]
    others = [np.asarray(measure.harmonics(r_best - c, n), dtype=float)[1:n] for i, c in enumerate(curves) if i != best]
    floor = np.median(others, axis=0) if others else np.zeros(HARMONIC_ORDERS)
    ratio = amp / np.maximum(floor, 1e-12)
    k = int(np.argmax(ratio)) + 1
    words = FOLD_WORDS.get(k, f"{k}-fold: fold placement or node count (what re-draping changes)")
    if ratio[k - 1] > 2.0:
        text = (f"The residual's strongest harmonic against the re-drape floor is k = {k} ({1000 * amp[k - 1]:.2f} mm, "
                f"{ratio[k - 1]:.1f}x the floor {1000 * floor[k - 1]:.2f} mm): {words}.")
    else:
        text = (f"No residual harmonic k = 1..{HARMONIC_ORDERS} stands out of the re-drape floor (largest ratio "
                f"{ratio[k - 1]:.1f}x at k = {k}): the residual looks like re-draping.")
    return {"harmonics_m": amp.tolist(), "redrape_floor_m": floor.tolist(), "dominant_k": k, "words": text}, \
        {"r_measured": r_obs, "r_best": r_best, "residual": residual}


def _pseudo_observations(pred, preset, models, offs, j, seed, config, lanes, progress, cancel_event, stream=0,
                         mean_material=False, positions=None):
    """`j` silhouettes of the preset's own predictive (posterior draws with placement noise, independent of the
    scored draws): what the measurement would look like if P were right. Forward drapes only (no record).
    `stream` 1, 2 draw other, independent sets (the step test's extra references, the re-drape floor's);
    `mean_material`: every drape of P's mean material and effects, only the placement differs (re-draping alone).
    `positions` (a list): the drapes' positions are appended to it, in the order of the silhouettes returned."""
    if mean_material:
        mean = copy.deepcopy(preset)
        bend = mean["posterior"]["bend"]
        bend["log_std"] = np.zeros_like(np.asarray(bend["log_std"], dtype=float)).tolist()
        bend["global_log_std"] = 0.0
        draws = infer.preset_bend_samples(mean, models[0].num_bending_edges, np.random.default_rng([seed, 23, stream]), j)
        values = fit_effects.active_effect_values(pred.effects)
        effects = [values] * j if values else None
    else:
        draws = infer.preset_bend_samples(preset, models[0].num_bending_edges,
                                          np.random.default_rng([seed, 23] if stream == 0 else [seed, 23, stream]), j)
        effects = fit_effects.sample_effect_values(pred.effects, np.random.default_rng(
            [seed, 29] if stream == 0 else [seed, 29, stream]), j)
    amplitude, modes = pred.placement
    rest = models[0].rest_positions
    images, xs = [None] * j, [None] * j

    def run(lane):
        m = models[lane]
        for i in range(lane, j, lanes):
            if cancel_event is not None and cancel_event.is_set():
                return
            p = m.parameters(stretch=pred.stretch, bend=draws[i], effects={**(effects[i] if effects else {}), **offs})
            v0 = infer.placement_velocities(rest, np.random.default_rng([seed, PSEUDO_SEED_OFFSET * (1 + stream) + i, 1]),
                                            amplitude, modes) if amplitude > 0 else None
            try:
                got = _forward_silhouette(m, p, v0, pred, config, cancel_event, with_positions=positions is not None)
            except Cancelled:
                return
            images[i], xs[i] = got if positions is not None else (got, None)
            if images[i] is None:
                continue
            what = ("the score's null reference", "the step test's references", "the re-drape floor")[stream]
            _progress(progress, "draws", f"predictive silhouette {i + 1}/{j} draped ({what})")

    _in_lanes(run, lanes)
    if positions is not None:
        positions += [x for im, x in zip(images, xs) if im is not None]
    return [im for im in images if im is not None]


def _pairs(n):
    """All unordered index pairs of range(n), in a fixed order (the scatter vectors cycle through them)."""
    return [(a, b) for a in range(n) for b in range(a + 1, n)]


def _scatter_image(i, pseudo, observed, pseudo_pairs, observed_pairs):
    """Draw i's scatter image (module doc, 2.): a zero-mean image whose outer product has expectation
    Cov(pseudo)/J + Cov(observed)/n, from one pair of predictive silhouettes and one pair of measured ones (a second,
    disjoint predictive pair stands in for the measurement when fewer than two images were given)."""
    a, b = pseudo_pairs[i % len(pseudo_pairs)]
    u = (pseudo[a] - pseudo[b]) / math.sqrt(2 * len(pseudo))
    if observed_pairs:
        c, d = observed_pairs[i % len(observed_pairs)]
        u = u + (observed[c] - observed[d]) / math.sqrt(2 * len(observed))
    else:
        rest = [q for q in pseudo_pairs if a not in q and b not in q]
        c, d = rest[i % len(rest)]
        u = u + (pseudo[c] - pseudo[d]) / math.sqrt(2 * len(observed))
    return u


def _joint_drapes(preset, observations, names, k, seed, config, threads, template_dir, mesh_level, progress,
                  cancel_event, keep_positions=False):
    """Drapes K draws of the preset on one model with every candidate active at its off values (P's own effects
    at their sampled values), recording the rollout; returns the shapes (x, hard image, dc, nodes, amplitude),
    per draw the score (the gradient of the excess data term, module doc 2.) for every candidate parameter and,
    under "scatter", the same gradient of the draw's scatter image, the predictive silhouettes used, and the draws'
    inputs (material draws, P's effect draws, the candidates' off values) for the step test."""
    reg = fit_effects.registry()
    shape = observations[0].mask.shape
    lanes = max(1, min(int(threads or min(os.cpu_count() or 1, 2)), k))
    pred = infer._Predictive(preset, shape, 1, config, template_dir, mesh_level, "dynamic")
    base_effects = fit_effects.sample_effect_values(pred.effects, np.random.default_rng([seed, 11]), k)
    offs = {n: {p["name"]: p["off"] for p in reg[n]["parameters"]} for n in names}
    p_active = fit_effects.active_effect_values(pred.effects)
    mesh = infer.sim.cusick_specimen(pred.level, template_dir=template_dir)
    models = [infer.sim.ClothModel(mesh, heterogeneous=True, density=preset["density_kg_m2"],
                                   effects={**p_active, **offs}, px_per_m=pred.calibration.px_per_m)
              for _ in range(lanes)]
    renderers = [render.SoftRenderer(pred.camera, sigma=config["render_sigma_px"]) for _ in range(lanes)]
    second = second_directions(reg)
    turned = {n: {**offs[n], **second[n]} for n in names if n in second}
    turned_keys = [f"{n}.{reg[n]['parameters'][0]['name']}" for n in turned]
    draws = infer.preset_bend_samples(preset, models[0].num_bending_edges, np.random.default_rng(seed), k)
    keys = [f"{n}.{p['name']}" for n in names for p in reg[n]["parameters"]]
    sigma_obs = float(config["sigma_obs"])
    amplitude, modes = pred.placement
    rest = models[0].rest_positions
    shapes, grads = [None] * k, [None] * k
    velocities = [infer.placement_velocities(rest, np.random.default_rng([seed, i, 1]), amplitude, modes)
                  if amplitude > 0 else None for i in range(k)]
    # what the step test (_step_drapes) needs to drape the same draws with an effect switched on
    light = _ForwardModels(mesh, preset["density_kg_m2"], p_active, pred.calibration.px_per_m, lanes)
    drawn = {"bend": draws, "effects": base_effects, "offs": offs, "velocities": velocities, "light": light}
    done = [0]
    lock = threading.Lock()
    t0 = time.monotonic()

    # the null reference: P's own predictive silhouettes, as many as there are images (at least PSEUDO_MIN)
    observed = [o.mask for o in observations]
    j = max(PSEUDO_MIN, len(observed))
    drawn["pseudo_x"] = [] if keep_positions else None  # their positions (the 3D step test's references)
    pseudo = _pseudo_observations(pred, preset, light.plain, {}, j, seed, config, lanes, progress, cancel_event,
                                  positions=drawn["pseudo_x"])
    if len(pseudo) < PSEUDO_MIN:
        if cancel_event is not None and cancel_event.is_set():
            return pred, models, shapes, grads, time.monotonic() - t0, lanes, pseudo, drawn
        raise SolverError(f"diagnose: only {len(pseudo)} of {j} predictive drapes of the preset succeeded "
                          f"(the score test needs {PSEUDO_MIN})")
    scale = 1.0 / (sigma_obs ** 2 * observed[0].size)  # the pixel data term's gradient per unit image difference
    excess = (np.mean(pseudo, axis=0) - np.mean(observed, axis=0)) * scale
    pseudo_pairs = _pairs(len(pseudo))
    observed_pairs = _pairs(len(observed))

    def scores(m, r, x, p, image_grads, bend, pt):
        """Per image gradient, the candidates' scores at p and, with `pt` (the turned directions' parameters: the
        same rollout, the primary being off), the turned primaries' from the same adjoint."""
        out, out_turned = [], []
        for w in image_grads:
            g = infer._observed_backward(m, x, p, r.backward(w), cancel_event,
                                         alternatives=None if pt is None else [pt])
            if pt is not None:
                g, gt = g
                out_turned.append({key: float(gt[key]) for key in turned_keys})
            d = {key: float(g[key]) for key in keys}
            # the nuisance direction: the material's overall bending scale, d data / d log(scale)
            d["bend.log_scale"] = float(np.sum(np.asarray(g["bend"]) * bend))
            out.append(d)
        return out, (out_turned or [None] * len(out))

    def run(lane):
        m, r = models[lane], renderers[lane]
        for i in range(lane, k, lanes):
            if cancel_event is not None and cancel_event.is_set():
                return
            effects = {**(base_effects[i] if base_effects else {}), **offs}
            p = m.parameters(stretch=pred.stretch, bend=draws[i], effects=effects)
            v0 = velocities[i]
            try:
                x = m.simulate(p, mode="dynamic", record=True, velocities0=v0, cancel_event=cancel_event,
                               **config["dynamic"])
            except SolverError as e:
                shapes[i] = {"error": str(e)}
                continue
            except Cancelled:  # mid-rollout: this draw is dropped, the finished ones are kept
                return
            hard = infer._hard_image(pred.camera, infer._observed(m, x, p), m.faces)
            nodes = measure.analyse_nodes(measure.r_theta(hard, pred.calibration))
            r.render(infer._observed(m, x, p), m.faces)  # the soft render whose adjoint carries the scores back
            # draws 2m and 2m + 1 share a scatter image: the cross products of their scatter scores estimate the
            # covariance through the mean adjoint (score_test)
            scatter = _scatter_image(i // 2, pseudo, observed, pseudo_pairs, observed_pairs) * scale
            # the turned directions (registry second_direction, e.g. a tilt's azimuth by 90 degrees): the same model
            # and rollout, the direction parameter turned, scored from the same adjoint (ClothModel.backward's
            # alternatives; until 2026-11-29 a second recorded rollout and backward per draw)
            pt = (m.parameters(stretch=pred.stretch, bend=draws[i],
                               effects={**(base_effects[i] if base_effects else {}), **turned}) if turned else None)
            try:
                (g, gu), (gt, gtu) = scores(m, r, x, p, [excess, scatter], draws[i], pt)
            except Cancelled:
                return
            shapes[i] = {"x": x, "image": hard, "dc": measure.drape_coefficient(hard, pred.calibration.px_per_m),
                         "nodes": nodes.count, "amplitude": nodes.amplitude_m}
            g["scatter"] = gu
            if turned:
                for n in turned:
                    primary = reg[n]["parameters"][0]["name"]
                    for q in second[n]:
                        g[f"{n}.{primary}@{q}"] = gt[f"{n}.{primary}"]
                        gu[f"{n}.{primary}@{q}"] = gtu[f"{n}.{primary}"]
            grads[i] = g
            with lock:
                done[0] += 1
                _progress(progress, "draws", f"draw {done[0]}/{k} draped and differentiated "
                                             f"({time.monotonic() - t0:.1f} s)", done=done[0], total=k)

    _in_lanes(run, lanes)
    return pred, models, shapes, grads, time.monotonic() - t0, lanes, pseudo, drawn


def refit_order(entries, threshold=None):
    """`entries` (ranking entries with p_value and, where the step test ran, step.p_value and step.statistic) in the
    order they are refitted (module doc, 3.): with a `threshold`, the significant ones (p below it) first; within
    each group by the sum of their ranks in the two tests (the combined p, smallest first; the step test's p,
    smallest first, then its statistic, most negative first), ties to the better step rank. A candidate without a
    step test ranks after every one with it there (p 1, statistic 0), so without a step test this is the p order.
    (Until 2026-11-28 the step rank went by the statistic alone: the relabelling p saturated. With the specimen
    null's continuous p the raw statistic put prestrain's refit before a stiffness map's whose step p was 500x
    smaller, on the round-trip test's drapes.)"""
    if threshold is not None:
        return (refit_order([e for e in entries if e["p_value"] < threshold])
                + refit_order([e for e in entries if e["p_value"] >= threshold]))

    def stat(e):
        st = e.get("step") or {}
        return (float(st.get("p_value", 1.0)), float(st.get("statistic", 0.0)))
    by_p = sorted(entries, key=lambda e: (e["p_value"], stat(e)))
    by_step = sorted(entries, key=lambda e: (stat(e), e["p_value"]))
    rank_p = {id(e): i for i, e in enumerate(by_p)}
    rank_step = {id(e): i for i, e in enumerate(by_step)}
    return sorted(entries, key=lambda e: (rank_p[id(e)] + rank_step[id(e)], rank_step[id(e)]))


def change_3d(entry):
    """The most negative `change` over an entry's 3D steps (step_tests' per_step: the draws' mean fold-feature
    distance to the measured meshes, its change), or its best step's best-of-K fall, negated, without per-step
    changes; None without either."""
    st = entry["step_3d"]
    changes = [float(x["change"]) for x in st.get("per_step") or []
               if x.get("change") is not None and math.isfinite(x["change"])]
    if changes:
        return min(changes)
    fall = st.get("best_of_k_fall")
    return -float(fall) if fall is not None and math.isfinite(fall) else None


def refit_order_3d(order, found):
    """`order` (refit_order's) with the entries found in 3D (`found(e)`, found_in_3d's) re-sorted among the places
    they hold by change_3d (the step that brings the draws' fold features closest to the measured meshes on
    average), the most negative first, then by the 3D statistic; the others stay where they were (module doc, 3b).
    Where P is far from the meshes in 3D every step that moves the fold features towards them is rejected with a
    small p, and the smallest p's go to the most consistent moves, not the largest (fabric 4: tilt's 3D p 1.6e-6
    for a best-of-K fall of 0.77, high_curvature_bending's 7.1e-4 for 2.26; the three refits went to tilt,
    bending_anisotropy and damping). Nor does the statistic order them: it is the step's change projected on the
    gap between the meshes and P's drapes (the references' change subtracted), linear in the step, while the
    distance also grows with the step's square (fabric 4: prestrain's statistic -10.9, the largest, for a best-of-K
    fall of -2.69; its refit raised the 3D error 6.86 -> 7.99). The best-of-K fall itself, on the screen's three
    draws, put rest_curvature (1.77) before high_curvature_bending (1.57) on fabric 2, and its refit closed 8 % of
    the gap; the mean change averages over the draws."""
    places = [i for i, e in enumerate(order) if found(e)]

    def key(e):
        c = change_3d(e)
        return (c if c is not None else math.inf, float(e["step_3d"]["statistic"]))
    by_change = sorted((order[i] for i in places), key=key)
    out = list(order)
    for i, e in zip(places, by_change):
        out[i] = e
    return out


def with_effect_values(preset, name, values):
    """A copy of `preset` with effect `name`'s values set to `values` ({parameter: value}; the others kept), each
    fitted parameter's interval moved with its value and its sd kept: a refit preset taken back to its start."""
    out = copy.deepcopy(preset)
    for param, v in values.items():
        e = out["active_effects"][name][param]
        shift = float(v) - float(e["value"])
        e["value"] = float(v)
        if e.get("interval90"):
            e["interval90"] = [float(b) + shift for b in e["interval90"]]
    return infer.validate_preset(out)


def with_effect(preset, name, values):
    """A copy of `preset` with effect `name` on at `values` ({parameter: value}, all of its parameters), not fitted
    (no sd: every draw has these values): a point of the refit's line search."""
    out = copy.deepcopy(preset)
    out["active_effects"] = {**(out.get("active_effects") or {}),
                             **fit_effects.EffectPlan({name: values}).preset_block()}
    return infer.validate_preset(out)


def search_evaluations(entry, k=DEFAULT_SAMPLES):
    """How many evaluations of k draws the refit's search costs at most for registry entry `entry`: line_search's
    points, or grid_search's (its points on SEARCH_GRID_DRAWS draws each, in evaluations of k, and its finalists)."""
    grid = grid_points(entry)
    if grid:
        return len(grid) * (SEARCH_GRID_DRAWS + SEARCH_GRID_CALL_DRAWS) / max(int(k), 1) + SEARCH_GRID_FINALISTS
    turns = 2 if len(entry.get("step_parameters") or []) == 2 else 0
    return len(SEARCH_FACTORS) + turns + 2


def grid_points(entry):
    """The grid search's points for registry entry `entry` ([{parameter: value}], every parameter; the off point
    first), or [] for an effect searched along a line: the square grid of the registry's search_grid_spacing in the
    plane of its two step_parameters, out to search_grid_reach from the off values, clipped to the bounds
    (duplicates dropped)."""
    h, reach = float(entry.get("search_grid_spacing") or 0.0), float(entry.get("search_grid_reach") or 0.0)
    stepped = stepped_parameters(entry)
    if h <= 0 or reach < h or len(stepped) != 2:
        return []
    params = {q["name"]: q for q in entry["parameters"]}
    off = {q: float(params[q]["off"]) for q in params}
    a, b = stepped
    n = int(math.floor(reach / h + 1e-9))
    cells = sorted(((i, j) for i in range(-n, n + 1) for j in range(-n, n + 1)
                    if math.hypot(i, j) * h <= reach * (1 + 1e-9)), key=lambda c: (math.hypot(*c), c))
    out, seen = [], set()
    for i, j in cells:
        v = dict(off)
        for q, c in ((a, i), (b, j)):
            v[q] = float(np.clip(off[q] + c * h, params[q]["lower"], params[q]["upper"]))
        key = (round(v[a], 12), round(v[b], 12))
        if key not in seen:
            seen.add(key)
            out.append(v)
    return out


def grid_search(entry, mse_of, k, draws=SEARCH_GRID_DRAWS, finalists=SEARCH_GRID_FINALISTS):
    """The refit's grid search (module doc, 3.) for registry entry `entry` with a search grid (grid_points): every
    point scored by `mse_of(values, draws)` (the best-of-`draws` MSE on the search's own draws, None when they all
    failed), then the `finalists` best again by `mse_of(values, k)` (the search's K draws). Why: an offset's
    landscape is basins 3-5 mm wide with steps between them, and its drapes take the same folds whatever the
    placement noise (docs/lab/effect-recovery.md), so a few draws find the basin where a line search from the best
    step did not (docs/diagnose.md, "Measured: the offset's grid search"). Returns (best values, points [{values,
    mse, draws, finalist}] in the order draped); the off point wins where no other point scores better (then the
    refit starts from off)."""
    points = []
    for v in grid_points(entry):
        mse = mse_of(v, draws)
        points.append({"values": v, "mse": None if mse is None else float(mse), "draws": int(draws),
                       "finalist": False})
    ranked = sorted((pt for pt in points if pt["mse"] is not None), key=lambda pt: pt["mse"])[:max(int(finalists), 1)]
    final = []
    for pt in ranked:
        mse = mse_of(pt["values"], k)
        final.append({"values": dict(pt["values"]), "mse": None if mse is None else float(mse), "draws": int(k),
                      "finalist": True})
    points += final
    best = min((pt for pt in final if pt["mse"] is not None), key=lambda pt: pt["mse"], default=None)
    if best is None:
        return None, points
    return dict(best["values"]), points


def line_search(entry, step, mse_of, vertex_within=0.0):
    """The refit's line search (module doc, 3.): from the step test's best step `step` ({parameter: value}, all
    of registry entry `entry`'s parameters), the stepped parameters' distance from off times t in SEARCH_FACTORS
    (the others as in the step, e.g. the tilt's turned azimuth), each scored by `mse_of(values)` (the best-of-K MSE
    on the search's own draws, None when they all failed). An effect that steps two parameters first turns the step
    by +- SEARCH_TURN_RAD in their plane at t = 1 (bending_anisotropy: its axis by +- 22.5 degrees) and keeps the
    best turn. When the best t is the last / first factor, t = 3 / 0.25 is draped too; then, when the best t lies
    between two draped ones, the vertex of the parabola through it and its neighbours. Values are clipped to the
    registry's bounds; a point whose clipped values were already scored is not draped again. The result is the
    point with the smallest MSE, or the vertex when it scores within `vertex_within` (an MSE) of it: the vertex
    pools three points' noise where the smallest is one point's (over the 46 searches of the confusion runs of
    2026-11-25..29 whose vertex was draped it lay closer to the truth: median |t - truth| 0.077 against the
    smallest point's 0.104, closer in 10 of the 11 where the two differed; docs/diagnose.md). Returns (best values,
    points [{t, turn_rad, values, mse, vertex}] in the order draped)."""
    params = {q["name"]: q for q in entry["parameters"]}
    stepped = stepped_parameters(entry)
    d0 = np.array([float(step[q]) - float(params[q]["off"]) for q in stepped])
    points, seen = [], {}

    def at(t, turn):
        d = d0
        if turn:
            c, s = math.cos(turn), math.sin(turn)
            d = np.array([c * d0[0] - s * d0[1], s * d0[0] + c * d0[1]])
        v = {q: float(x) for q, x in step.items()}
        for q, x in zip(stepped, d):
            v[q] = float(np.clip(params[q]["off"] + t * x, params[q]["lower"], params[q]["upper"]))
        return v

    def score(t, turn, vertex=False):
        v = at(t, turn)
        key = tuple(round(v[q], 12) for q in sorted(v))
        if key not in seen:
            mse = mse_of(v)
            seen[key] = math.inf if mse is None else float(mse)
            points.append({"t": float(t), "turn_rad": float(turn), "values": v,
                           "mse": None if mse is None else float(mse), "vertex": vertex})
        return seen[key]

    turn = 0.0
    if len(stepped) == 2:
        turn = min((0.0, -SEARCH_TURN_RAD, SEARCH_TURN_RAD), key=lambda a: score(1.0, a))
    ts = sorted(SEARCH_FACTORS)
    f = {t: score(t, turn) for t in ts}
    i = min(range(len(ts)), key=lambda j: f[ts[j]])
    if i in (0, len(ts) - 1):
        t = ts[0] / 2 if i == 0 else ts[-1] + 2 * (ts[-1] - ts[-2])
        f[t] = score(t, turn)
    ts = sorted(f)
    i = min(range(len(ts)), key=lambda j: f[ts[j]])
    if 0 < i < len(ts) - 1:
        (t0, f0), (t1, f1), (t2, f2) = [(ts[j], f[ts[j]]) for j in (i - 1, i, i + 1)]
        # the vertex of the parabola through the three points (t1 is the lowest, so it lies between t0 and t2)
        den = (t1 - t0) * (f1 - f2) - (t1 - t2) * (f1 - f0)
        if den != 0 and all(math.isfinite(x) for x in (f0, f1, f2)):
            t = t1 - 0.5 * ((t1 - t0) ** 2 * (f1 - f2) - (t1 - t2) ** 2 * (f1 - f0)) / den
            score(float(np.clip(t, t0, t2)), turn, vertex=True)
    best = min((pt for pt in points if pt["mse"] is not None), key=lambda pt: pt["mse"], default=None)
    vertex = next((pt for pt in points if pt["vertex"] and pt["mse"] is not None), None)
    if vertex is not None and vertex["mse"] <= best["mse"] + max(0.0, float(vertex_within)):
        best = vertex
    return (dict(step) if best is None else dict(best["values"])), points


def refit_mode(budget, spare, evaluation, full, has_start, can_search=None):
    """How a refit runs under a time budget (module doc, Time budget): "epochs" when its equal share of the time
    left pays for epochs (`budget` > 0 s); else, for a refit that can search (`can_search`, by default `has_start`:
    a line search needs a start, a step that brought the draws closer; a grid search does not), "search" when
    `spare` (the time left less one evaluation per later refit) pays for its `full` evaluations (its search's best
    point is then the refit); else, for a refit with a start, "step" when `spare` pays for one evaluation (the step
    itself is the refit); else None (not refitted)."""
    if budget > 0:
        return "epochs"
    if (has_start if can_search is None else can_search) and spare >= full:
        return "search"
    if has_start and spare >= evaluation:
        return "step"
    return None


def refit_path(job, name):
    """Per accepted epoch of `job`: its loss, batch MSE and effect `name`'s values after the epoch's step."""
    return [{"epoch": h["epoch"], "loss": h.get("loss"), "mse": h.get("mse"),
             "values": {key.split(".", 1)[1]: v for key, v in h["effects"].items() if key.split(".", 1)[0] == name}}
            for h in job.history if "rejected" not in h and h.get("effects")]


def refit_with_effect(preset, images, name, level, seed, config, threads=None, template_dir=None, budget=None,
                      cancel_event=None, progress=None, spec=None, sigma_dc=None, start=None):
    """Short refit with `name` fitted from P's material (see the module doc); returns the refit preset and its
    FitJob. Also the recovery table's refit (tools/effect_recovery.py). spec: the effect's entry in the fit's
    effects argument (fit_effects.EffectPlan): None fits all its parameters (diagnose's refit), e.g.
    {"strain": None} fits only that one (the others off). sigma_dc: None keeps the score test's pixel term only
    (SCORE_SIGMA_DC); a number adds the fit's drape-coefficient term with that sd (and its soft-bias estimate).
    start: {parameter: value} of the effect to start from (the diagnosis's best step, module doc 3.) instead of the
    fit's start search among the off value and +- moderate strengths, which judges them by one drape without
    placement noise."""
    cfg = copy.deepcopy(config)
    # the fit's start search (without `start`) on one drape from flat, as the refits' time plan assumes (the
    # confusion tables were measured so): fit.json's placement drapes would multiply its drapes
    cfg["effects"] = dict(infer.effect_settings(cfg), start_search_drapes=1)
    if start is not None:  # a fine-tune from a step near the answer: smaller steps (measured: docs/diagnose.md)
        cfg["effects"]["learning_rate"] = REFIT_START_LEARNING_RATE_FACTOR * float(cfg["effects"]["learning_rate"])
    log_std = float(np.mean(preset["posterior"]["bend"]["log_std"]))
    prior_sd = max(log_std, 1e-3)
    cfg["init"]["bdp_std"] = prior_sd
    cfg["prior"] = {"log_bend_mean": "start", "log_bend_std": prior_sd}
    cfg["calibration"]["enabled"] = False
    cfg["learning_rates"][preset["model"]] = {key: MATERIAL_LEARNING_RATE_FACTOR * float(v)
                                              for key, v in cfg["learning_rates"][preset["model"]].items()}
    # pixel term only, as in the score test: with the soft drape coefficient's bias the drape-coefficient term
    # pulled a tilt back towards zero (measured: 0.15 -> 0.03 rad in 8 epochs on a 0.3 rad tilt)
    cfg["sigma_dc"] = SCORE_SIGMA_DC if sigma_dc is None else float(sigma_dc)
    # P's tables (its stretching as it is, no scale search), placement noise and effects, `name` fitted
    options = infer.start_options(preset, {"config": cfg, "mesh_level": level}, {name: spec})
    job = infer.FitJob(images, preset["density_kg_m2"], model=preset["model"], seed=seed,
                       template_dir=template_dir, threads=threads, **options)
    if start is not None:
        vector = np.asarray(job.theta["effect_mu"], dtype=float).copy()
        for i, (effect, q) in enumerate(job.plan.free):
            if effect == name and q["name"] in start:
                vector[i] = float(start[q["name"]])
        job.theta["effect_mu"] = vector
        job.effect_start = {"parameters": job.plan.names, "candidates": [vector.tolist()],
                            "chosen": vector.tolist(), "from": "the diagnosis's step test"}
    if "eta" in job.theta:  # the material's posterior sd: P's, per entry
        job.theta["eta"] = infer.inverse_softplus(np.maximum(np.asarray(preset["posterior"]["bend"]["log_std"]), 1e-4))

    def epoch(e):
        fitted = "".join(f"  {key} {v:+.4g}" for key, v in (e.get("effects") or {}).items())
        _progress(progress, "refit", f"refit +{name}: epoch {e['epoch']} loss {e['loss']:.4f} MSE {e['mse']:.4f}"
                                     f"{fitted}", effect=name)

    if budget is None:
        job.run(epochs=int(cfg["default_epochs"]), progress=epoch, cancel_event=cancel_event)
    else:
        job.run(time_budget=budget, progress=epoch, cancel_event=cancel_event)
    refit = job.preset(options={"diagnose": True, "effects": job.plan.describe(), "seed": seed})
    job.averaged_epochs = 0
    if start is not None:  # the iterate average of the last epochs: the noisy batches' steps cancel
        path = refit_path(job, name)
        n = int(np.ceil(REFIT_AVERAGE_SHARE * len(path)))
        if n > 1:
            mean = {q: float(np.mean([h["values"][q] for h in path[-n:]])) for q in path[-1]["values"]}
            refit = with_effect_values(refit, name, mean)
            job.averaged_epochs = n
    g = preset["posterior"]["bend"].get("global_log_std")
    if g:  # the base predictive's calibrated per-draw spread, so that base and refit compare like for like
        refit["posterior"]["bend"]["global_log_std"] = float(g)
    refit["camera"] = dict(preset["camera"])
    refit["fabric"] = dict(preset.get("fabric") or {})
    return infer.validate_preset(refit), job


def diagnose(preset, images, meshes=None, candidates=None, time_budget=None, samples=None, seed=0, config=None,
             threads=None, template_dir=None, mesh_level=None, out_dir=None, progress=None, cancel_event=None,
             alpha=ALPHA, max_refits=MAX_REFITS, mesh_noise_m=fold_geometry.RECONSTRUCTION_NOISE_M):
    """Diagnoses `preset` (a path or a preset dict) against measured silhouettes (module doc); `max_refits`: how
    many of the most promising candidates are refitted (default MAX_REFITS); `mesh_noise_m`: the measured meshes'
    vertex noise sd [m], added to the simulated drapes' hinge angles in 3D (default the Cusick reconstructions';
    0 for noise-free meshes such as synth's). Returns the diagnosis
    dict; with `out_dir`, writes DIR/diagnosis.json (after every stage), DIR/presets/<effect>.json per refit and
    the report DIR/index.html with its PNGs. `progress` receives {stage, message, ...}; `cancel_event` stops
    cleanly: the diagnosis then holds what was done ("cancelled": true)."""
    t0 = time.monotonic()
    if isinstance(max_refits, bool) or not isinstance(max_refits, (int, np.integer)) or max_refits < 0:
        raise InputError(f"max_refits: a whole number >= 0, got {max_refits!r}")
    preset_path = os.fspath(preset) if isinstance(preset, (str, os.PathLike)) else None
    p, meshes, names, k = _check_inputs(preset, images, meshes, candidates, time_budget, samples)
    config = copy.deepcopy(config or infer.load_config())
    if out_dir:
        if os.path.exists(out_dir) and not os.path.isdir(out_dir):
            raise InputError(f"report: {out_dir} exists and is not a folder")
        os.makedirs(out_dir, exist_ok=True)
        measure.check_output_path(os.path.join(out_dir, "diagnosis.json"), "diagnosis")
    observations = _observations(images)
    images_key = _images_key([o.sha256 for o in observations])
    earlier = _earlier_history(preset_path, out_dir, images_key)
    reg = fit_effects.registry()
    second = second_directions(reg)
    alpha = float(alpha)
    if not 0 < alpha <= 1:
        raise InputError(f"alpha: a significance level in (0, 1], got {alpha}")
    mesh_noise_m = float(mesh_noise_m)
    if not 0 <= mesh_noise_m < 0.01:
        raise InputError(f"mesh_noise: the measured meshes' vertex noise sd, in [0, 10) mm, got {1000 * mesh_noise_m:g} mm")
    switches = [n for n in names if _is_switch(reg[n])]
    named = {str(c).strip() for c in (candidates.split(",") if isinstance(candidates, str) else (candidates or []))}

    def explicit_switch(n):
        return n in named
    tested_names = [n for n in names if n not in switches]
    threshold = alpha / max(1, len(tested_names))
    label = (p.get("fabric") or {}).get("name") or (os.path.basename(preset_path) if preset_path else "preset")
    result = {"preset": preset_path, "model": p["model"], "images": list(images), "samples": k, "seed": int(seed),
              "candidates": names, "base": None, "ranking": [], "recommended": None, "alternatives": [],
              "threshold": threshold,
              "threshold_rule": f"alpha {alpha:g} Bonferroni-corrected over the {len(tested_names)} candidates tested "
                                f"({alpha:g} / {len(tested_names)}): the family-wise chance of naming an effect on data "
                                f"without one stays below {alpha:g}",
              "switches": switches,
              "test": "Hotelling T^2 of the per-draw score (pixel data term gradient at the off value, the bending "
                      "scale's part projected out, norms capped), p from sign flips of the draws; p_value_f: "
                      "Hotelling's F(q, K - 1 - q), p_value_chi2: the asymptotic chi2(q); with the step test (the "
                      "draws at the effect's moderate strength, p against n re-drapes of one specimen drawn from P) "
                      "p_value = min(1, 2 min(p_value_score, step.p_value))",
              "material_prior": None, "history": [], "cancelled": False, "seconds": {}}
    figures = {"images": []}

    def save():
        result["seconds"]["total"] = time.monotonic() - t0
        if out_dir:
            os.makedirs(out_dir, exist_ok=True)
            measure.write_json(os.path.join(out_dir, "diagnosis.json"), _public(result))

    try:
        # 1. where it fails, and the score tests (one rollout + backward per draw)
        _progress(progress, "draws", f"{label}: {k} posterior draws on {len(images)} image(s), score tests of "
                                     f"{', '.join(names) or 'no candidates'}")
        pred, models, shapes, grads, seconds, lanes, pseudo, drawn = _joint_drapes(
            p, observations, names, k, seed, config, threads, template_dir, mesh_level, progress, cancel_event,
            keep_positions=bool(meshes))
        result["seconds"]["draws"] = seconds
        result["mesh_level"] = pred.level
        done = [i for i in range(k) if shapes[i] is not None and "error" not in shapes[i]]
        result["failed_draws"] = sum(1 for s in shapes if s is not None and "error" in s)
        if cancel_event is not None and cancel_event.is_set():
            result["cancelled"] = True
        if not done:
            if result["cancelled"]:
                save()
                return result
            raise SolverError(f"diagnose: every one of the {k} posterior draws failed to drape")
        base, per_image, ok = _summary([shapes[i] for i in done], observations, pred.calibration,
                                       float(config["sigma_obs"]), SCORE_SIGMA_DC)
        # the re-drape floor: the draws against P's mean material re-draped (placement noise only)
        tr = time.monotonic()
        redrape_x = [] if meshes else None  # the re-drapes' positions (the 3D step test, with meshes)
        redrapes = _pseudo_observations(pred, p, drawn["light"].plain, {}, max(REDRAPE_FLOOR_MIN, len(observations)),
                                        seed, config, lanes, progress, cancel_event, stream=2, mean_material=True,
                                        positions=redrape_x)
        forward_measured = (time.monotonic() - tr) / len(redrapes) if redrapes else None
        floor = _redrape_floor([shapes[i] for i in done], redrapes)
        if floor is not None:
            base["redrape_mse"], base["redrape_mse_sd"] = floor
        base["redrape_change_mse"] = redrape_change(redrapes)
        result["base"] = base
        for o, e in zip(observations, per_image):
            sig, curves = _signature(o, ok, e["best_draw"], pred.calibration)
            e["signature"] = sig
            e["outside_interval"] = _outside_words(e)
            figures["images"].append({"mask": o.mask, "best": ok[e["best_draw"]]["image"], **curves})
        for e, mesh in zip(per_image, meshes):  # the best draw's mesh against the measured one
            e["hausdorff_m"] = float(measure.hausdorff_distance((ok[e["best_draw"]]["x"], models[0].faces), mesh))
        mesh3d, f_measured, mesh_test = None, None, None  # the 3D step test's features (module doc, 2c)
        distance_3d = None  # the 3D error's feature distance, once the 3D step test has run
        if meshes:  # where in 3D: fold shape per ring, crest and edge hinge angles (drapelab.fold_geometry)
            result["geometry"] = geometry_3d(meshes, [s["x"] for s in ok], models[0], seed, mesh_noise_m)
            measured_x, why = measured_positions(meshes, models[0])
            if measured_x is None:
                mesh_test = {"skipped": why}
            else:
                mesh3d = MeshFeatures(models[0].rest_positions, models[0].bending_edges, mesh_noise_m, seed)
                f_measured = [mesh3d.measured(x) for x in measured_x]
                mesh_test = {"measured_meshes": len(f_measured), "noise_m": mesh_noise_m}
        result["per_image"] = per_image
        result["draws_used"] = len(done)
        per_draw = seconds * lanes / max(1, len(done))
        # ranking
        g_done = [grads[i] for i in done]
        for n in names:
            params = reg[n]["parameters"]
            keys = [f"{n}.{q['name']}" for q in params]
            scales = [q["prior_scale"] for q in params]
            for q in second.get(n, {}):
                keys.append(f"{keys[0]}@{q}")
                scales.append(params[0]["prior_scale"])
            entry = {"effect": n, "parameters": keys, "statistic": None, "p_value": None, "refit": None,
                     "gain": None, "explanation": None, "switch": n in switches}
            if n in switches:
                entry["explanation"] = (f"{reg[n]['explanation']}. Predicts {reg[n]['signature']}. A switch: its "
                                        f"primary parameter ({params[0]['name']}) chooses the model's structure, so "
                                        "it has no score at its off value; judged by its refit alone"
                                        + ("." if explicit_switch(n) else
                                           " (refitted only when named: --candidates " + n + ")."))
            elif len(g_done) >= MIN_SAMPLES:
                st = score_test([[g[key] for key in keys] for g in g_done], scales,
                                clip=SCORE_CLIP_FACTOR,
                                nuisance=[g["bend.log_scale"] for g in g_done],
                                scatter=[[g["scatter"][key] for key in keys] for g in g_done],
                                scatter_nuisance=[g["scatter"]["bend.log_scale"] for g in g_done],
                                scatter_groups=[i // 2 for i in done])
                entry.update(statistic=st["statistic"], p_value=st["p_value"], p_value_f=st["p_value_f"],
                             p_value_chi2=st["p_value_chi2"],
                             rank=st["rank"], clipped_draws=st["clipped"], gradient_mean=dict(zip(keys, st["gradient_mean"])))
                pull = ", ".join(f"{key} {'up' if gm < 0 else 'down'}" for key, gm in zip(keys, st["gradient_mean"])
                                 if gm != 0)
                verdict = "significant" if st["p_value"] < threshold else "not significant"
                entry["explanation"] = (f"{reg[n]['explanation']}. Predicts {reg[n]['signature']}. Score T^2 "
                                        f"{st['statistic']:.3g} on {st['rank']} dof, p = {st['p_value']:.2g} "
                                        f"({verdict} at {threshold:.2g}); the data pull {pull or 'nothing'}.")
            else:
                entry["explanation"] = f"{reg[n]['explanation']}. Not tested: fewer than {MIN_SAMPLES} draws draped."
            result["ranking"].append(entry)
        result["seconds"]["score"] = time.monotonic() - t0
        # 1b. the step test: the same draws with each candidate at its moderate strength (module doc, 2b)
        steps = effect_steps(reg, names, second)
        n_steps = sum(len(v) for v in steps.values())
        k_step = len(done)
        forward_step = None  # a forward drape's wall time measured on the step test's drapes
        test_s = None  # the step tests' own computation per draw and step (seconds), measured on the first tests
        k_screen = None
        j_step = max(STEP_REFERENCES_MIN, 4 * len(observations))
        # a forward drape's wall time: measured on the re-drape floor's drapes, else estimated from the draws
        forward = forward_measured or per_draw * STEP_FORWARD_SHARE / lanes
        left = None
        steps_dropped = []  # "effect:label" of the steps the budget did not pay for (steps_within)
        if time_budget is not None and n_steps:  # the extra references and the step drapes within a share
            left = float(time_budget) - (time.monotonic() - t0)
            full = n_steps
            steps, k_step, steps_dropped = steps_within(steps, effect_steps(reg, names, second, diagonals=False),
                                                        {e["effect"]: e["p_value"] for e in result["ranking"]},
                                                        k_step, left, forward, max(0, j_step - len(pseudo)))
            n_steps = sum(len(v) for v in steps.values())
            if steps_dropped:
                _progress(progress, "steps", f"step test: the budget pays for {MIN_SAMPLES} draws on {n_steps} of "
                                             f"{full} steps; dropped {', '.join(steps_dropped)}")
            if MIN_SAMPLES <= k_step and k_step < SCREEN_BELOW * len(done):  # thin: screen, then confirm
                k_screen = min(k_step, SCREEN_DRAWS)
        tests, tests3d = {}, {}
        # (the specimen test's p is continuous, so any number of images can reach the threshold: until 2026-11-28
        # the relabelling test was not run where its smallest p, 2 / C(n + J, n), could not)
        if n_steps and k_step < MIN_SAMPLES:
            result["step_test"] = {"draws": 0, "references": 0, "dropped_steps": steps_dropped,
                                   "rule": f"not run: the time budget left room for {k_step} draws per step "
                                           f"({MIN_SAMPLES} needed) on {n_steps} step(s)"}
        if n_steps and k_step >= MIN_SAMPLES and not result["cancelled"]:
            ts = time.monotonic()
            k_first = k_screen or k_step
            _progress(progress, "steps", f"step test{' screen' if k_screen else ''}: {n_steps} steps of {len(steps)} "
                                         f"candidates x {k_first} draws")
            j_extra = j_step - len(pseudo)
            references = list(pseudo)
            reference_x = None if mesh3d is None else list(drawn["pseudo_x"])
            if j_extra > 0:
                references += _pseudo_observations(pred, p, drawn["light"].plain, {}, j_extra, seed, config, lanes,
                                                   progress, cancel_event, stream=1, positions=reference_x)
            used = done[:k_first]
            tf = time.monotonic()
            step_x = None if mesh3d is None else {}
            images_k = _step_drapes(pred, drawn, steps, used, config, lanes, progress, cancel_event,
                                    positions=step_x)
            if mesh3d is not None:
                f_references = [mesh3d.simulated(x, (1, r)) for r, x in enumerate(reference_x)]
                f_redrapes = [mesh3d.simulated(x, (3, r)) for r, x in enumerate(redrape_x)]
                scale_3d = feature_scale(f_measured, f_references + f_redrapes)  # the tests' and the 3D error's

            def tests_3d(draw_ids, positions, subset):
                """The 3D step test of the steps `subset` on the draws `draw_ids` (their step drapes' positions)."""
                if mesh3d is None:
                    return {}
                f_base = [mesh3d.simulated(shapes[i]["x"], (0, i)) for i in draw_ids]
                # a step drape's vertex noise is its draw's (common random numbers): a step that leaves the drape
                # as it is (the camera's) changes no feature, and the noise does not enter the step's change
                f_steps = {key: [mesh3d.simulated(x, (0, draw_ids[u])) for u, x in enumerate(v)]
                           for key, v in positions.items() if key[0] in subset}
                out = step_tests_3d(f_base, f_steps, subset, f_measured, f_references, f_redrapes, scale_3d)
                for st in out.values():
                    st["draws"] = len(draw_ids)
                return out
            # the latest forward drape time, on these models and lanes: what the confirmation and the refits'
            # evaluations are planned with (one estimate for both: 1.43 s a drape on circle3, as the floor's)
            forward_step = (time.monotonic() - tf) / max(1, len(used) * n_steps)
            screen_info = None
            if cancel_event is not None and cancel_event.is_set():
                result["cancelled"] = True
            else:
                observed = [o.mask for o in observations]
                tt = time.monotonic()
                tests = step_tests([shapes[i]["image"] for i in used], images_k, steps, observed, references,
                                   redrapes)
                tests3d = tests_3d(used, step_x, steps)
                # the tests' own computation per draw and step (pixel MSEs against every image, the relabellings):
                # a confirmation repeats it on all its draws
                test_s = (time.monotonic() - tt) / max(1, len(used) * n_steps)
                for st in tests.values():
                    st["draws"] = len(used)
                if k_screen is not None:  # confirm the promising on fresh draws, within the screen's share
                    reserved = refits_reserved({e["effect"]: e["p_value"] for e in result["ranking"]}, threshold,
                                               int(max_refits))
                    kept_back = REPORT_RESERVE_S + reserved * k * forward_step * EVALUATION_OVERHEAD
                    room = left - (time.monotonic() - ts) - kept_back
                    # the confirmation is chosen by the silhouettes' screen; the 3D step test stays on the screen's
                    # draws for every candidate (its p chooses nothing, so it needs no correction; module doc, 2c)
                    confirmed, m = confirmation_plan(tests, {n: len(v) for n, v in steps.items()}, room, forward_step,
                                                     len(done) - k_screen, k_screen, test_s)
                    screen_info = {"draws": k_screen, "p_max": SCREEN_P_MAX, "passed": sorted(
                        n for n, st in tests.items() if st["p_value"] < SCREEN_P_MAX), "confirmed": confirmed,
                        "confirmation_draws": m}
                    for st in tests.values():
                        st["screen"] = {"draws": k_screen, "statistic": st["statistic"], "p_value": st["p_value"],
                                        "step": st["step"]}
                    if confirmed:
                        _progress(progress, "steps", f"step test: confirming {', '.join(confirmed)} on {m} fresh "
                                                     "draws")
                        fresh = done[k_screen:k_screen + m]
                        sub = {n: steps[n] for n in confirmed}
                        n_sub = sum(len(v) for v in sub.values())
                        # no drape starts once the reserved evaluations, the report's reserve, the tests' own time
                        # and one drape in flight per lane would no longer fit (a plan is an estimate; this holds it)
                        deadline = (t0 + float(time_budget) - kept_back
                                    - (test_s or 0.0) * n_sub * (k_screen + m) - forward_step * lanes)
                        more = _step_drapes(pred, drawn, sub, fresh, config, lanes, progress, cancel_event,
                                            deadline=deadline)
                        fresh = fresh[:len(next(iter(more.values()), []))]
                        screen_info["confirmation_draws"] = len(fresh)
                        if len(fresh) < m:
                            screen_info["confirmation_planned"] = m
                        if cancel_event is not None and cancel_event.is_set():  # the screen's tests stand
                            result["cancelled"] = True
                        elif fresh:
                            both = used + fresh
                            merged = {key: images_k[key] + more[key] for key in more}
                            for n, st in step_tests([shapes[i]["image"] for i in both], merged, sub, observed,
                                                    references, redrapes).items():
                                tests[n] = {**st, "draws": len(both), "screen": tests[n]["screen"]}
                    for st in tests.values():  # unconfirmed (on the screen's draws only): at least SCREEN_P_MAX
                        if st["draws"] == k_screen:
                            st["p_value"] = max(st["p_value"], SCREEN_P_MAX)
            result["seconds"]["steps"] = time.monotonic() - ts
            if mesh3d is not None and tests3d:  # the 3D errors (best-of-K feature distance) of the base and its floor
                distance_3d = feature_distance(*scale_3d)
                f_drawn = [mesh3d.simulated(shapes[i]["x"], (0, i)) for i in done]
                base["error_3d"] = best_of_k_3d(f_drawn, f_measured, distance_3d)
                base["redrape_error_3d"] = best_of_k_3d(f_drawn, f_redrapes, distance_3d)
            if mesh_test is not None and "skipped" not in mesh_test:
                names_3d = next((st["features"] for st in tests3d.values()), [])
                mesh_test.update(features=names_3d, tested=sorted(tests3d),
                                 rule="the same step drapes, each compared by its 3D fold features (crest and hoop "
                                      "hinge angles per band, height and fold amplitude per ring; the simulated "
                                      "drapes' angles with the measured meshes' vertex noise) instead of its "
                                      "silhouette: the mean squared feature difference over the references' sd, "
                                      "against the measured meshes, P's own drapes and the re-drapes; the same "
                                      "specimen null; p_value = min(1, 3 min(score p, step p, 3D step p))")
            result["step_test"] = {"draws": len(used), "references": len(references), "redrapes": len(redrapes),
                                   "mesh": mesh_test,
                                   "screen": screen_info, "forward_s": forward_step, "test_s": test_s,
                                   "steps": n_steps, "dropped_steps": steps_dropped,
                                   "rule": "per candidate the primary parameter at +- its moderate strength (and "
                                           "turned, for the tilt); the change of the draws' mean pixel MSE against "
                                           "the measured images minus against P's own predictive silhouettes; p "
                                           "against n re-drapes of one specimen drawn from P (the variance "
                                           "between specimens from the references, within one from the re-drapes "
                                           "and the measured images, integrated over both estimates' uncertainty; "
                                           "the smallest step's p corrected for the choice "
                                           "of step by the steps' correlation); "
                                           "p_value = min(1, 2 min(score p, step p))"
                                           + ("" if screen_info is None else
                                              f"; screened on {k_screen} draws, the candidates with screen p below "
                                              f"{SCREEN_P_MAX:g} confirmed on fresh draws as the budget allows (their "
                                              "step p from all their draws)")
                                           + ("" if not steps_dropped else
                                              f"; {len(steps_dropped)} step(s) the budget did not pay for at "
                                              f"{MIN_SAMPLES} draws dropped (dropped_steps: the plane diagonals "
                                              "first, then the candidates with the largest score p)")}
        for entry in result["ranking"]:
            st = tests.get(entry["effect"])
            if st is None:
                if tests and any(d.startswith(entry["effect"] + ":") for d in steps_dropped):
                    entry["explanation"] += (" Not step-tested: the time budget paid for the step test on the "
                                             "more promising candidates only (its score p is among the largest).")
                continue
            direction = step_direction(reg[entry["effect"]], second.get(entry["effect"]), st["per_step"])
            if direction is not None:
                st["direction"] = direction
            entry["step"] = st
            entry["p_value_score"] = entry["p_value"]
            st3 = tests3d.get(entry["effect"])
            if st3 is not None:
                entry["step_3d"] = st3
            entry["p_value"] = combined_p(entry["p_value"], st["p_value"], st3 and st3["p_value"])
            verdict = "significant" if entry["p_value"] < threshold else "not significant"
            screened = st.get("screen")
            if screened is not None:
                if st["draws"] > screened["draws"]:
                    how = f"confirmed on {st['draws'] - screened['draws']} fresh draws"
                elif screened["p_value"] >= SCREEN_P_MAX:
                    how = f"not confirmed: its p is above {SCREEN_P_MAX:g}"
                else:
                    how = f"not confirmed: no time was left for its draws (its step p counts as {SCREEN_P_MAX:g})"
                entry["explanation"] += f" Step screen on {screened['draws']} draws: p = {screened['p_value']:.2g}, {how}."
            entry["explanation"] += (f" Step test ({st['step']}): the draws' MSE against the measurements moves "
                                     f"{st['statistic']:+.2g} relative to P's own drapes, p = {st['p_value']:.2g}"
                                     + ("" if st3 is None else
                                        f"; in 3D ({st3['step']}) their fold features' distance moves "
                                        f"{st3['statistic']:+.2g}, p = {st3['p_value']:.2g}")
                                     + f"; combined p = {entry['p_value']:.2g} ({verdict}).")
        # ties: with K = 16 draws the sign-flip p-value cannot go below 2 / 2^16 = 3.1e-5 (the step test's is
        # continuous); the step statistic, then Hotelling's F break them
        result["ranking"].sort(key=lambda e: (e["p_value"] is None, e["p_value"] if e["p_value"] is not None else 1.0,
                                              (e.get("step") or {}).get("statistic", 0.0),
                                              e.get("p_value_f") if e.get("p_value_f") is not None else 1.0))
        save()
        if result["cancelled"]:
            raise Cancelled()

        # 2. refits of the most promising candidates
        tested = [e for e in result["ranking"] if e["p_value"] is not None]

        def in_3d(e):
            """found_in_3d, when the 3D error is measured."""
            return distance_3d is not None and bool(base.get("redrape_error_3d")) and found_in_3d(e, threshold)

        promising = (refit_order_3d(refit_order([e for e in tested if e["p_value"] < max(threshold, REFIT_P_MAX)],
                                                threshold), in_3d)[:int(max_refits)]
                     if any(e["p_value"] < threshold for e in tested) else [])
        for order, e in enumerate(promising):
            e["refit_order"] = order + 1
        promising += [e for e in result["ranking"] if e["switch"] and explicit_switch(e["effect"])]
        if promising:
            result["material_prior"] = ("the preset's posterior (log_mean, per-entry log_std, global_log_std), held "
                                        "fixed in the refit (material learning rates x "
                                        f"{MATERIAL_LEARNING_RATE_FACTOR:g}); only the effect is fitted")
        def start_for(e):
            """Refit e's start, refit_start's (values, how, label) from its 3D step test when it was found in 3D, else
            from its step test; (None, None, None) without a step that brought the draws closer."""
            if in_3d(e):
                return refit_start(e["step_3d"], by="change")
            return refit_start(e["step"]) if e.get("step") else (None, None, None)

        def start_of(e):
            return start_for(e)[0]

        grids = {e["effect"]: [] if in_3d(e) else grid_points(reg[e["effect"]]) for e in promising}  # [] for a line search

        def searched(e):
            """Whether refit e searches before its epochs: from a step start (line_search), or on its effect's
            grid (grid_search), which needs no start."""
            return start_of(e) is not None or bool(grids[e["effect"]])

        def evaluate(candidate, at_seed=seed, n=None, record=True, noise_key=None, floor_3d=False):
            """(shapes, summary) of n draws of `candidate` (by default the comparison's k_eval draws of the base's
            seed), or None when all fail. `record`: its seconds per draw plan the evaluations still to come (not a
            grid point's few draws, which a fresh model's setup weighs more). `noise_key` (two whole numbers: the
            base's (5, 0), a refit's (6, its candidate's index)): the summary also holds the draws' 3D error when
            the 3D step test ran (their hinge angles' noise drawn from it), and with `floor_3d` its re-drape floor."""
            n = k_eval if n is None else n
            rp = infer._Predictive(candidate, observations[0].mask.shape, lanes, config, template_dir, pred.level,
                                   "dynamic")
            te = time.monotonic()
            draws = infer.preset_bend_samples(candidate, rp.num_edges, np.random.default_rng(at_seed), n)
            rshapes = rp.drape(draws, at_seed, cancel_event=cancel_event)
            if record and not (cancel_event is not None and cancel_event.is_set()):
                evaluations_s.append((time.monotonic() - te) / n)
            if not any("error" not in r for r in rshapes):
                return None
            rbase, _, _ = _summary(rshapes, observations, rp.calibration, float(config["sigma_obs"]), SCORE_SIGMA_DC)
            if distance_3d is not None and noise_key is not None:  # the 3D error on the same draws (module doc, 2c)
                f_drawn = [None if "error" in r else mesh3d.simulated(r["x"], (*noise_key, i))
                           for i, r in enumerate(rshapes)]
                rbase["error_3d"] = best_of_k_3d(f_drawn, f_measured, distance_3d)
                if floor_3d:  # the base's: the 3D floor on these draws too
                    rbase["redrape_error_3d"] = best_of_k_3d(f_drawn, f_redrapes, distance_3d)
            return rshapes, rbase

        # an evaluation: K forward drapes, at the step test's measured drape time, else the re-drape floor's (else
        # `forward`, estimated from the draws)
        forward_known = forward_step or forward_measured
        estimated = k * (forward_known * EVALUATION_OVERHEAD if forward_known else forward)
        evaluations_s = []  # measured evaluations, seconds per draw: once there is one, their mean plans the rest
        result["refit_evaluations_measured_s_per_draw"] = evaluations_s
        k_eval = k  # the comparison's draws (set below, once the refits to run are known)

        def evaluation_s(n=None):
            """Seconds an evaluation of n draws (default the comparison's k_eval) takes."""
            n = k_eval if n is None else n
            return n * (float(np.mean(evaluations_s)) if evaluations_s else estimated / k)

        def evaluations_of(e, done=False):
            """Seconds of the evaluations refit e still needs: its search's (unless `done`; in evaluations of K
            draws), its end's and its start's (k_eval draws each)."""
            if not searched(e):
                return evaluation_s()
            return 2 * evaluation_s() + (0 if done else search_evaluations(reg[e["effect"]], k) * evaluation_s(k))

        def refit_budget(idx, done=False):
            """Seconds for refit idx's epochs: what is left, less the evaluations still to come (this refit's
            search unless `done`) and the report's reserve, shared equally by the refits still to run."""
            left = float(time_budget) - (time.monotonic() - t0)
            evaluations = sum(evaluations_of(e, done and i == idx) for i, e in enumerate(promising) if i >= idx)
            return (left - REPORT_RESERVE_S - evaluations) / (len(promising) - idx)

        if time_budget is not None:  # the least promising go first when the budget cannot pay one evaluation each
            left = float(time_budget) - (time.monotonic() - t0)
            while promising and len(promising) * estimated + REPORT_RESERVE_S > left:
                dropped = promising.pop()
                dropped["explanation"] += (f" Not refitted: the time budget left ({left:.0f} s) paid for "
                                           f"{len(promising)} refit evaluation(s) of about {estimated:.0f} s.")
            result["refit_evaluation_s"] = estimated
        if promising:
            # the comparison (module doc, 3.): the base and every refit's end and start on k_eval draws, as many as
            # COMPARISON_SHARE of the time left pays for (at least K, at most COMPARISON_SAMPLES_MAX)
            finals = 1 + sum(2 if searched(e) else 1 for e in promising)
            if time_budget is None:
                k_eval = max(k, COMPARISON_SAMPLES_MAX)
            else:
                left = float(time_budget) - (time.monotonic() - t0)
                k_eval = int(min(max(k, COMPARISON_SAMPLES_MAX),
                                 max(k, COMPARISON_SHARE * left / (finals * evaluation_s(1)))))
            comparison, paired = dict(base, samples=k), shapes  # paired: the base's draws, index by index
            if k_eval > k:
                _progress(progress, "refit", f"the base on {k_eval} draws (the refits' comparison)")
                got = evaluate(p, noise_key=(5, 0), floor_3d=True)
                if got is None:
                    k_eval = k
                else:
                    cmp_ok = [s_ for s_ in got[0] if "error" not in s_]
                    comparison, paired = dict(got[1], samples=k_eval), got[0]
                    floor_eval = _redrape_floor(cmp_ok, redrapes)
                    if floor_eval is not None:
                        comparison["redrape_mse"], comparison["redrape_mse_sd"] = floor_eval
            result["comparison"] = comparison

        for idx, entry in enumerate(promising):
            budget = None
            found_3d = bool(in_3d(entry))
            start, how, start_step = start_for(entry)
            step_only = False
            if time_budget is not None:
                budget = refit_budget(idx)
                # what this refit may spend when each later one gets a single evaluation (its step, or its end)
                spare = (float(time_budget) - (time.monotonic() - t0) - REPORT_RESERVE_S
                         - (len(promising) - idx - 1) * evaluation_s())
                mode = refit_mode(budget, spare, evaluation_s(), evaluations_of(entry), start is not None,
                                  searched(entry))
                if mode is None:
                    entry["explanation"] += " Not refitted: the time budget was spent."
                    continue
                step_only = mode == "step"
            ts = time.monotonic()
            search = None
            grid = grids[entry["effect"]]
            if start is not None and not grid:  # a grid search starts anywhere
                st = entry["step_3d"] if found_3d else entry["step"]
                if how == "change" and start_step != st["step"]:
                    entry["explanation"] += (f" The refit starts at the 3D step that brought the draws' fold features "
                                             f"closest to the meshes on average ({start_step}), not at the step with "
                                             f"the smallest 3D p ({st['step']}).")
                elif how == "harmonic":
                    entry["explanation"] += (f" Its steps' statistics follow a first harmonic around their plane (r2 "
                                             f"{st['direction']['r2']:.2f}) pointing at "
                                             f"{math.degrees(st['direction']['direction_rad']):.0f} degrees: the refit "
                                             "starts along it, not at the best single step.")
                elif start_step != st["step"]:
                    entry["explanation"] += (f" The refit starts at the step that brought the draws closest ({start_step}), "
                                             f"not at the step with the smallest p ({st['step']}).")
            if searched(entry) and not step_only:  # the search, on draws of its own (module doc, 3.)
                name = entry["effect"]
                search_seed = seed + SEARCH_SEED_OFFSET
                counter = itertools.count(1)

                def mse_of(values, n=k, name=name, search_seed=search_seed, grid=grid, counter=counter,
                           found_3d=found_3d):
                    got = evaluate(with_effect(p, name, values), search_seed, n, record=n >= k,
                                   noise_key=(7, names.index(name)) if found_3d else None)
                    what = (f"grid search {name} {next(counter)}/{len(grid) + SEARCH_GRID_FINALISTS}" if grid
                            else f"line search {name}" + (" in 3D" if found_3d else ""))
                    _progress(progress, "refit", f"{what}: " + " ".join(f"{q} {v:+.4g}" for q, v in values.items())
                              + (" failed" if got is None else f" best-of-{n} MSE {got[1]['mse']:.4f}"
                                 + (f", 3D error {got[1]['error_3d']:.4g}" if found_3d else "")), effect=name)
                    return None if got is None else got[1]["error_3d" if found_3d else "mse"]
                if grid:
                    best, points = grid_search(reg[name], mse_of, k)
                    spacing = float(reg[name]["search_grid_spacing"])
                    search = {"seed": search_seed, "step": None if start is None else dict(start), "points": points,
                              "best": best, "grid": {"spacing": spacing, "reach": float(reg[name]["search_grid_reach"]),
                                                     "draws": SEARCH_GRID_DRAWS, "finalists": SEARCH_GRID_FINALISTS},
                              "seconds": time.monotonic() - ts}
                    first = stepped_parameters(reg[name])[0]
                    unit = next(q["unit"] for q in reg[name]["parameters"] if q["name"] == first)
                    if best is not None:
                        entry["explanation"] += (f" Grid search over its plane ({len(grid)} points {spacing:g} {unit} apart "
                                                 f"on {SEARCH_GRID_DRAWS} draws of their own, the best "
                                                 f"{SEARCH_GRID_FINALISTS} on {k}): " + ", ".join(
                                                     f"{q} {v:+.4g}" for q, v in best.items()) + ".")
                else:
                    vertex_within = SEARCH_VERTEX_WITHIN * float(base.get("redrape_error_3d" if found_3d else
                                                                          "redrape_mse") or 0.0)
                    best, points = line_search(reg[name], start, mse_of, vertex_within)
                    search = {"seed": search_seed, "step": dict(start), "points": points, "best": best,
                              "vertex_within": vertex_within, "seconds": time.monotonic() - ts,
                              "scored_by": "error_3d" if found_3d else "mse"}
                    entry["explanation"] += (f" Line search along the {'3D ' if found_3d else ''}step ({len(points)} "
                                             "points on draws of their own"
                                             + (", scored by the 3D error" if found_3d else "") + "): "
                                             + ", ".join(f"{q} {v:+.4g}" for q, v in best.items()) + ".")
                start = best if best is not None else start
                if time_budget is not None:
                    budget = refit_budget(idx, done=True)
            job = None
            if not step_only and not found_3d and (budget is None or budget > 0):
                _progress(progress, "refit", f"refit with {entry['effect']} "
                                             f"({'default epochs' if budget is None else f'{budget:.0f} s'})",
                          effect=entry["effect"])
                refit, job = refit_with_effect(p, images, entry["effect"], pred.level, seed, config, threads,
                                               template_dir, budget, cancel_event, progress, start=start)
                evaluated = evaluate(refit, noise_key=(6, names.index(entry["effect"])))
                end = {"values": fit_effects.active_effect_values(refit["active_effects"])[entry["effect"]],
                       "mse": evaluated[1]["mse"] if evaluated else None}
            kept_start = False
            if job is None and start is None:  # a grid search whose every point failed, and no step start
                entry["explanation"] += (" Not refitted: none of its 3D steps brought the draws closer to the measured "
                                         "meshes." if found_3d else
                                         " Not refitted: every point of its search failed to drape.")
                continue
            if job is None:  # the search spent the refit's share: its best point, on the base's draws, is the refit
                refit, end, kept_start = with_effect(p, entry["effect"], start), None, True
                evaluated = evaluate(refit, noise_key=(6, names.index(entry["effect"])))
                entry["explanation"] += (" No line search, no epochs: the time budget left paid for one evaluation, so "
                                         "the refit is the step test's best step." if step_only else
                                         " Found in 3D, fitted in 3D: the refit is the line search's best point, with "
                                         "no epochs (the fit's epochs see the silhouettes only)." if found_3d else
                                         " No epochs: the search spent the refit's share of the time budget.")
            elif start is not None:  # the refit's start, on the same draws: kept when the refit's end is worse
                started = with_effect_values(refit, entry["effect"], start)
                at_start = evaluate(started, noise_key=(6, names.index(entry["effect"])))
                if at_start is not None and (evaluated is None or at_start[1]["mse"] < evaluated[1]["mse"]):
                    entry["explanation"] += (f" The refit's end (best-of-{k_eval} MSE "
                                             + (f"{evaluated[1]['mse']:.4f}" if evaluated else "failed")
                                             + ") was worse than its start, the search's best point, "
                                               "which is kept.")
                    refit, evaluated, kept_start = started, at_start, True
            if evaluated is None:
                entry["explanation"] += f" Refit: every one of its {k_eval} draws failed to drape."
                continue
            rshapes, rbase = evaluated
            values = fit_effects.active_effect_values(refit["active_effects"])[entry["effect"]]
            entry["refit"] = {"mse": rbase["mse"], "iou": rbase["iou"], "loss": rbase["loss"],
                              "dc_error": rbase["dc_error"], "node_error": rbase["node_error"],
                              "amplitude_error": rbase["amplitude_error"], "samples": k_eval,
                              "epochs": 0 if job is None else job.epoch,
                              "seconds": time.monotonic() - ts, "values": values,
                              "strength_of_moderate": strength_of_moderate(reg[entry["effect"]], values, second),
                              "effect_change_mse": effect_change(paired, rshapes), "kept_start": kept_start,
                              "end": end, "averaged_epochs": 0 if job is None else job.averaged_epochs,
                              "path": [] if job is None else refit_path(job, entry["effect"]), "search": search}
            if rbase.get("error_3d") is not None:
                entry["refit"]["error_3d"] = rbase["error_3d"]
            entry["refit"]["fitted_in"] = "3d" if found_3d else "silhouettes"
            entry["gain"] = (comparison["loss"] - rbase["loss"]) / len(reg[entry["effect"]]["parameters"])
            entry["explanation"] += (f" Refit ({entry['refit']['epochs']} epochs): loss {comparison['loss']:.4g} -> "
                                     f"{rbase['loss']:.4g}, best-of-{k_eval} MSE {comparison['mse']:.4f} -> "
                                     f"{rbase['mse']:.4f}"
                                     + (f"; in 3D the fold features' best-of-{k_eval} distance "
                                        f"{comparison['error_3d']:.3g} -> {rbase['error_3d']:.3g}"
                                        if rbase.get("error_3d") is not None and comparison.get("error_3d") is not None
                                        else "") + ".")
            refit.setdefault("training", {})["init"] = {"preset": preset_path, "model": p["model"],
                                                        "fabric": (p.get("fabric") or {}).get("name"),
                                                        "by": "diagnose refit"}
            if out_dir:
                path = os.path.join(out_dir, "presets", f"{entry['effect']}.json")
                os.makedirs(os.path.dirname(path), exist_ok=True)
                infer.write_preset(path, refit)
                entry["refit"]["preset"] = os.path.relpath(path, out_dir)
            result["history"].append(_history_entry(f"{label} + {entry['effect']}", refit, dict(rbase, samples=k_eval),
                                                    "diagnose refit"))
            save()
    except Cancelled:
        result["cancelled"] = True
        _progress(progress, "cancelled", "cancelled: writing what is done")

    # the refits are judged against the base on the comparison's draws (k_eval of them; the base's own K when no
    # refit ran)
    judged = result.get("comparison") or result.get("base") or {}
    base_mse, redrape, k_judged = judged.get("mse"), judged.get("redrape_mse"), int(judged.get("samples") or k)
    for e in result["ranking"]:
        e["mse_fall"] = ((base_mse - e["refit"]["mse"]) / base_mse
                         if e["refit"] is not None and base_mse else None)
        e["fall_of_redrape"] = ((base_mse - e["refit"]["mse"]) / redrape
                                if e["refit"] is not None and base_mse and redrape else None)
        # in 3D: the refit's fall of the best-of-K feature distance, in units of its re-drape floor (module doc, 2c)
        base_3d, floor_3d = judged.get("error_3d"), judged.get("redrape_error_3d")
        refit_3d = (e["refit"] or {}).get("error_3d")
        if refit_3d is not None and base_3d is not None and floor_3d:
            e["fall_3d_of_redrape"] = (base_3d - refit_3d) / floor_3d
    # the final order: refits that lower the error, most first (which effect explains the difference), then the
    # score tests' order (whether the data differ from P at all: module doc, 3.)
    falling = sorted([e for e in result["ranking"] if e["mse_fall"] is not None and e["mse_fall"] > 0],
                     key=lambda e: -e["mse_fall"])
    result["ranking"] = falling + [e for e in result["ranking"] if e not in falling]
    any_significant = any(e["p_value"] is not None and e["p_value"] < threshold for e in result["ranking"])
    gaining = [e for e in falling if (any_significant or e["switch"]) and e["mse_fall"] >= MIN_MSE_FALL]
    small = [e for e in gaining if e["fall_of_redrape"] is not None and e["fall_of_redrape"] < MIN_FALL_OF_REDRAPE]
    gaining = [e for e in gaining if e not in small]
    # found and fitted in 3D (module doc, 3b): recommended when no refit is by the silhouettes and
    # recommendable_in_3d's conditions hold (the 3D fall, the outline as good as the base's, the drape coefficient
    # error within the measured drape coefficients' standard error of the base's)
    base_3d = judged.get("error_3d")
    dc_within = dc_standard_error(result.get("per_image"))
    in_3d_gaining = recommendable_in_3d(result["ranking"], base_3d, judged.get("redrape_error_3d"), base_mse, redrape,
                                        any_significant, judged.get("dc_error"), dc_within)
    if not gaining and in_3d_gaining:
        best = in_3d_gaining[0]
        result["recommended"] = best["effect"]
        result["ranking"] = [best] + [e for e in result["ranking"] if e is not best]
        written = out_dir and best["refit"].get("preset")
        refit_file = os.path.join(out_dir, best["refit"]["preset"]) if written else None
        result["verdict"] = (
            f"{best['effect']} is {why_in_3d(best, result['ranking'], threshold)} and "
            f"its refit, fitted in 3D, lowers the fold features' best-of-{k_judged} distance to the measured meshes by "
            f"{100 * (base_3d - best['refit']['error_3d']) / base_3d:.0f} % ({base_3d:.3g} -> "
            f"{best['refit']['error_3d']:.3g}, {best['fall_3d_of_redrape']:.2f} of its re-drape floor) while the "
            f"silhouettes' best-of-{k_judged} MSE stays within half their re-drape floor ({base_mse:.4f} -> "
            f"{best['refit']['mse']:.4f}): " + (f"the refit is {refit_file}; the silhouettes alone do not fit it, so keep "
                                                f"its value (fit --init {refit_file} fits the material with it fixed)"
                                                if refit_file else f"set {best['effect']} to its refit's value"))
    elif gaining:
        best = gaining[0]
        result["recommended"] = best["effect"]
        written = out_dir and best["refit"].get("preset")
        refit_file = os.path.join(out_dir, best["refit"]["preset"]) if written else None
        why = ("a switch judged by its refit alone" if best["switch"] else
               (f"significant (p = {best['p_value']:.2g} < {threshold:.2g})" if best["p_value"] < threshold else
                f"the refit that explains the significant difference best (its own p = {best['p_value']:.2g})"))
        result["verdict"] = (f"{best['effect']} is {why} and its refit lowers the best-of-{k_judged} MSE by "
                             f"{100 * best['mse_fall']:.0f} % ({base_mse:.4f} -> {best['refit']['mse']:.4f}): "
                             + (f"the refit is {refit_file}; fit --init {refit_file} --effects {best['effect']} "
                                f"fits the effect and the material together from it" if refit_file
                                else f"fit --effects {best['effect']}"))
        result["alternatives"] = alternatives([best] + [e for e in falling if e is not best], redrape)
        result["verdict"] += alternatives_words(result["alternatives"], best["effect"], k_judged)
    else:
        tested = [e for e in result["ranking"] if e["p_value"] is not None]
        significant = [e for e in tested if e["p_value"] < threshold]
        smallest = min((e["p_value"] for e in tested), default=None)
        if significant:
            in_3d_refits = [e for e in tested if (e["refit"] or {}).get("fitted_in") == "3d"]  # significant or not
            refitted = [e["effect"] for e in significant if e["refit"] is not None and e not in small
                        and e not in in_3d_refits]
            not_run = [e["effect"] for e in significant if e["refit"] is None]
            why = [f"the refit with {e['effect']} removes {base_mse - e['refit']['mse']:.4f} of the best-of-{k_judged} MSE, "
                   f"{e['fall_of_redrape']:.2f} of the re-drape floor {redrape:.4f} (at least "
                   f"{MIN_FALL_OF_REDRAPE:g} needed): it changes the drape less than re-draping does"
                   for e in small if (e["refit"] or {}).get("fitted_in") != "3d"]
            if refitted:
                why.append(f"the refit with {', '.join(refitted)} did not lower the best-of-{k_judged} MSE by "
                           f"{100 * MIN_MSE_FALL:.0f} %")
            for e in in_3d_refits:  # fitted in 3D: what it did in 3D and to the silhouettes (recommendable_in_3d)
                fall = e.get("fall_3d_of_redrape")
                why.append(f"the refit with {e['effect']}, fitted in 3D, moved the fold features' best-of-{k_judged} "
                           f"distance {base_3d if base_3d is not None else float('nan'):.3g} -> "
                           f"{e['refit'].get('error_3d') if e['refit'].get('error_3d') is not None else float('nan'):.3g}"
                           + (f" ({fall:.2f} of its re-drape floor)" if fall is not None else "")
                           + f" and the silhouettes' best-of-{k_judged} MSE {base_mse:.4f} -> {e['refit']['mse']:.4f}"
                           + (f" and the drape coefficient error {judged['dc_error']:.3f} -> "
                              f"{e['refit']['dc_error']:.3f}" if judged.get("dc_error") is not None
                              and e["refit"].get("dc_error") is not None else "")
                           + f" (a recommendation needs a 3D fall of {MIN_FALL_OF_REDRAPE:g} floors and "
                           f"{100 * MIN_3D_GAP_SHARE:.0f} % of the gap above the 3D floor, with the MSE at most "
                           f"{ALTERNATIVE_WITHIN:g} of its floor above the base's"
                           + (f" and the drape coefficient error at most {dc_within:.3f} (the measured drape "
                              "coefficients' standard error) above the base's" if dc_within is not None else "")
                           + ")")
            if not_run:
                reason = not_refitted_reason(result["cancelled"], max_refits)
                why.append(f"{', '.join(not_run)} not refitted ({reason})")
            result["verdict"] = (f"No recommendation: {', '.join(e['effect'] for e in significant)} below the "
                                 f"threshold {threshold:.2g}, but {'; '.join(why)}.")
        else:
            why = ("no candidate was tested" if smallest is None else
                   f"the smallest p-value is {smallest:.2g} against the threshold {threshold:.2g} "
                   f"({result['threshold_rule']})")
            # switches have no test: say what their refits did (a switch named in --candidates, e.g. disk_contact)
            switched = [e for e in result["ranking"] if e.get("switch") and e["refit"] is not None and base_mse]
            said = [f"the refit with {e['effect']} (a switch, judged by its refit alone) "
                    f"{'raised' if e['refit']['mse'] > base_mse else 'lowered'} the best-of-{k_judged} MSE "
                    f"({base_mse:.4f} -> {e['refit']['mse']:.4f}; a recommendation needs a fall of "
                    f"{100 * MIN_MSE_FALL:.0f} %)" for e in switched]
            if said:
                why = "; ".join(said) if smallest is None else why + "; " + "; ".join(said)
            result["verdict"] = f"Nothing significant: {why}."
    if result["recommended"] is not None:  # beside either recommendation: what was not refitted that might compete
        result["not_refitted"] = unrefitted(result["ranking"], threshold, exclude=(result["recommended"],))
        result["verdict"] += unrefitted_words(result["not_refitted"], result["recommended"],
                                              not_refitted_reason(result["cancelled"], max_refits)) + "."
    if judged.get("error_3d") is not None and any_significant:
        result["unrefitted_3d"] = unrefitted_3d(result["ranking"], threshold)
        result["verdict"] += unrefitted_3d_words(result["unrefitted_3d"])
    # every entry measured on these images carries their fingerprint; P's training metrics only when P was
    # trained on exactly these images
    trained_here = _provenance_key(p) == images_key
    current = [h if h["source"] == TRAINING_SOURCE and not trained_here else dict(h, images=images_key)
               for h in _history(p, label, result.get("comparison") or result.get("base")) + result["history"]]
    mine = {_entry_key(h) for h in _public(current)}
    result["history"] = [h for h in earlier if _entry_key(h) not in mine] + current
    save()
    if out_dir and result.get("base") is not None:
        write_report(out_dir, result, figures, observations, pred.calibration)
    result["seconds"]["total"] = time.monotonic() - t0
    return _public(result)


def _history_entry(model, preset, metrics, source):
    effects = {n: {q: e["value"] for q, e in params.items()} for n, params in (preset.get("active_effects") or {}).items()}
    return {"model": model, "effects": effects, "source": source,
            **{key: metrics.get(key) for key in ("mse", "iou", "dc_error", "node_error", "amplitude_error", "loss",
                                                 "samples") if key != "samples" or metrics.get(key) is not None}}


TRAINING_SOURCE = "preset training metrics"  # history entries of a preset's own training batch (not charted)


def _provenance_key(preset):
    """_images_key of the images a preset was trained on (its provenance), or None when it does not say."""
    hashes = [i.get("sha256") for i in ((preset.get("provenance") or {}).get("images") or []) if isinstance(i, dict)]
    if not hashes or not all(isinstance(h, str) for h in hashes):
        return None
    return _images_key(hashes)


def _history(p, label, base):
    out = []
    training = (p.get("metrics") or {}).get("training_image") or {}
    if training.get("mse") is not None:
        out.append(_history_entry(f"{label} (training image)", p, {"mse": training.get("mse"), "iou": training.get("iou")},
                                  TRAINING_SOURCE))
    if base is not None:
        out.append(_history_entry(label, p, base, "diagnose base"))
    return out


MAX_LINEAGE = 16  # presets followed back through training.init when gathering earlier model versions


def _images_key(hashes):
    """One fingerprint of a set of measurements from their content hashes (sha256 hex): the sha256 of the sorted
    hashes (the order and the file names do not matter)."""
    return hashlib.sha256("".join(sorted(hashes)).encode()).hexdigest()


def _entry_key(h):
    """What makes two history entries the same model version measured the same way."""
    return h["model"], h.get("source"), h.get("mse"), h.get("dc_error")


def _lineage(preset_path):
    """The presets P was started from, nearest first: P's training.init.preset (fit --init, or the preset a
    diagnosis refitted), its own, and so on (paths as recorded; a relative one is looked up from the working
    folder, then from the folder of the preset that names it). Stops at a preset that is missing, unreadable or
    already seen."""
    out, seen, current = [], set(), preset_path
    while current and len(out) < MAX_LINEAGE:
        try:
            with open(current) as f:
                init = ((json.load(f).get("training") or {}).get("init") or {}).get("preset")
        except (OSError, ValueError, AttributeError, RecursionError):
            break
        if not isinstance(init, str) or not init:
            break
        found = next((c for c in ([init] if os.path.isabs(init) else
                                  [init, os.path.join(os.path.dirname(current), init)]) if os.path.isfile(c)), None)
        if found is None or os.path.realpath(found) in seen:
            break
        seen.add(os.path.realpath(found))
        out.append(found)
        current = found
    return out


def _earlier_history(preset_path, out_dir, images_key):
    """Model versions measured earlier on the same measurements (CONVENTIONS.md, model history): the history
    entries with this run's images fingerprint from the report being rewritten (out_dir/diagnosis.json) and from
    the report of every preset in P's lineage that is a diagnosis's refit (REPORT/presets/NAME.json), oldest
    report first, each entry once. Each keeps its model, metrics and source, with "report" naming where it was
    read (relative to out_dir, else absolute)."""
    reports = []
    for ancestor in reversed(_lineage(preset_path) if preset_path else []):
        folder = os.path.dirname(os.path.abspath(ancestor))
        if os.path.basename(folder) == "presets":
            reports.append(os.path.join(os.path.dirname(folder), "diagnosis.json"))
    if out_dir:
        reports.append(os.path.join(out_dir, "diagnosis.json"))
    out, seen_reports, seen = [], set(), set()
    for report in reports:
        if os.path.realpath(report) in seen_reports or not os.path.isfile(report):
            continue
        seen_reports.add(os.path.realpath(report))
        try:
            with open(report) as f:
                history = json.load(f).get("history") or []
        except (OSError, ValueError, AttributeError, RecursionError):
            continue
        for h in history if isinstance(history, list) else []:
            if not isinstance(h, dict) or h.get("images") != images_key or not isinstance(h.get("model"), str):
                continue
            key = _entry_key(h)
            if key in seen:
                continue
            seen.add(key)
            where = os.path.relpath(report, out_dir) if out_dir else os.path.abspath(report)
            out.append({**h, "report": h.get("report") or where})
    return out


def _public(result):
    """JSON-safe copy (non-finite numbers as null)."""
    def clean(v):
        if isinstance(v, dict):
            return {key: clean(x) for key, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        if isinstance(v, (np.floating, float)):
            return float(v) if math.isfinite(v) else None
        if isinstance(v, np.integer):
            return int(v)
        return v
    return clean(result)


# ---------------------------------------------------------------- report
def _geometry_figure(path, g):
    """The mean drape's profile per material ring (side view: R against z, the fold amplitude as bars) and the hinge
    angles per band, measured against the model (its 90 % interval over the draws)."""
    fig = _figure((8.0, 3.4))
    ax = fig.add_subplot(1, 2, 1)
    rings = [r for r in g["rings"] if r["R"]["measured"] is not None]  # a coarse mesh leaves rings unmeasured
    for who, colour in (("measured", "C3"), ("model", "C0")):
        R = [1000 * r["R"][who] for r in rings]
        z = [1000 * r["z"][who] for r in rings]
        a = [1000 * r["amplitude"][who] for r in rings]
        ax.errorbar(R, z, xerr=a, color=colour, marker="o", ms=3, capsize=2, label=f"{who} (bars: fold amplitude)")
    ax.set_xlabel("mean radius R (mm)")
    ax.set_ylabel("mean height z (mm)")
    ax.set_title("material rings r0 9.5 .. 14.5 cm", fontsize=9)
    ax.legend(fontsize=7)
    ax2 = fig.add_subplot(1, 2, 2)
    labels, x = [], 0
    for b in g["bands"]:
        for key, name in (("crest_p99", "crest p99"), ("hoop_p95", "fall p95")):
            q = b[key]
            if q["interval90"] is None:
                continue
            ax2.plot([x, x], q["interval90"], color="C0", lw=6, alpha=0.4)
            ax2.plot(x, q["model"], "_", color="C0", ms=12)
            ax2.plot(x, q["measured"], "o", color="C3")
            labels.append(f"{name}\n{100 * b['r0_m'][0]:.0f}-{100 * b['r0_m'][1]:.0f} cm")
            x += 1
    ax2.set_xticks(range(len(labels)))
    ax2.set_xticklabels(labels, fontsize=6)
    ax2.set_ylabel("hinge angle (degrees)")
    ax2.set_title("measured (dots) against the draws' 90 % (bars)", fontsize=9)
    fig.tight_layout()
    _save(fig, path)


def _figure(size=(6.4, 3.6)):
    from matplotlib.figure import Figure
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    fig = Figure(figsize=size, dpi=110)
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path):
    def write(tmp):
        fig.savefig(tmp, format="png")
    measure._atomic_write(path, "figure", ".png", write)


def write_report(out_dir, result, figures, observations, calibration):
    """DIR/index.html and its PNGs: overlays, r(theta) with residual, harmonic bars, predictive intervals, the
    ranking (-log10 p with the threshold line) and the history chart."""
    os.makedirs(out_dir, exist_ok=True)
    parts = [f"<h1>Diagnosis of {html.escape(str(result.get('preset') or 'preset'))}</h1>",
             f"<p><b>{html.escape(result.get('verdict', ''))}</b></p>"]
    if result.get("cancelled"):
        parts.append("<p><b>Cancelled</b>: this report holds what was done.</p>")
    b = result["base"]
    parts.append(f"<p>{result['draws_used']} posterior draws on circle{result.get('mesh_level')}: best-of-K MSE "
                 f"{b['mse']:.4f}, IoU {b['iou']:.4f}, |dDC| {b['dc_error']:.3f}, node error {b['node_error']:.2f}, "
                 f"amplitude error {1000 * b['amplitude_error']:.2f} mm, loss {b['loss']:.4g}"
                 + (f"; in 3D the fold features' best-of-K distance to the measured meshes {b['error_3d']:.3g} "
                    f"(re-drape floor {b['redrape_error_3d']:.3g})" if b.get("error_3d") is not None
                    and b.get("redrape_error_3d") is not None else "") + ".</p>")
    for i, (e, f) in enumerate(zip(result["per_image"], figures["images"])):
        name = html.escape(os.path.basename(e["image"]))
        over = f"overlay_{i}.png"
        measure.write_overlay(os.path.join(out_dir, over), f["mask"], f["best"], title=f"{os.path.basename(e['image'])}: "
                              f"best draw (MSE {e['mse']:.4f})", calibration=calibration)
        fig = _figure((7.0, 3.6))
        ax = fig.add_subplot(1, 2, 1)
        t = np.linspace(0, 360, len(f["r_measured"]), endpoint=False)
        ax.plot(t, 1000 * f["r_measured"], label="measured")
        ax.plot(t, 1000 * f["r_best"], label="best draw")
        ax.plot(t, 1000 * f["residual"] + 90.0, label="residual + 90 mm", color="k", lw=0.8)
        ax.set_xlabel("theta (deg)")
        ax.set_ylabel("r (mm)")
        ax.legend(fontsize=7)
        ax2 = fig.add_subplot(1, 2, 2)
        s = e["signature"]
        ks = np.arange(1, HARMONIC_ORDERS + 1)
        ax2.bar(ks - 0.2, 1000 * np.asarray(s["harmonics_m"]), 0.4, label="residual")
        ax2.bar(ks + 0.2, 1000 * np.asarray(s["redrape_floor_m"]), 0.4, label="re-drape floor")
        ax2.set_xlabel("harmonic k")
        ax2.set_ylabel("amplitude (mm)")
        ax2.legend(fontsize=7)
        fig.tight_layout()
        rt = f"rtheta_{i}.png"
        _save(fig, os.path.join(out_dir, rt))
        words = "".join(f"<li>{html.escape(w)}</li>" for w in [s["words"]] + e["outside_interval"])
        parts.append(f"<h2>{name}</h2><img src='{over}'><img src='{rt}'><ul>{words}</ul>")
    # predictive intervals
    fig = _figure((7.5, 3.0))
    for j, (key, what, factor) in enumerate((("drape_coefficient", "drape coefficient", 1.0),
                                             ("node_count", "node count", 1.0),
                                             ("node_amplitude_m", "node amplitude (mm)", 1000.0))):
        ax = fig.add_subplot(1, 3, j + 1)
        for i, e in enumerate(result["per_image"]):
            lo, hi = e[key]["interval90"]
            ax.plot([i, i], [factor * lo, factor * hi], color="C0", lw=6, alpha=0.4)
            ax.plot(i, factor * e[key]["observed"], "o", color="C3")
        ax.set_title(what, fontsize=9)
        ax.set_xticks(range(len(result["per_image"])))
        ax.set_xlabel("image")
    fig.tight_layout()
    _save(fig, os.path.join(out_dir, "intervals.png"))
    parts.append("<h2>Predictive 90 % intervals (bars) and measurements (dots)</h2><img src='intervals.png'>")
    geometry = result.get("geometry")
    if geometry and "skipped" in geometry:
        parts.append(f"<h2>In 3D</h2><p>{html.escape(geometry['skipped'])}</p>")
    elif geometry:
        _geometry_figure(os.path.join(out_dir, "geometry.png"), geometry)
        words = "".join(f"<li>{html.escape(w)}</li>" for w in geometry["words"]) or (
            "<li>The measured meshes lie within the model's 90 % intervals in every ring and band compared.</li>")
        parts.append("<h2>In 3D: the measured meshes against the draws</h2><img src='geometry.png'>"
                     f"<ul>{words}</ul>")
    # ranking
    ranked = [e for e in result["ranking"] if e["p_value"] is not None]
    fig = _figure((6.4, 0.6 + 0.5 * max(1, len(ranked))))
    ax = fig.add_subplot(1, 1, 1)
    y = np.arange(len(ranked))
    ax.barh(y, [-math.log10(max(e["p_value"], 1e-300)) for e in ranked], color="C0")
    ax.axvline(-math.log10(result["threshold"]), color="C3", ls="--", label=f"threshold p = {result['threshold']:.2g}")
    ax.set_yticks(y)
    ax.set_yticklabels([e["effect"] for e in ranked])
    ax.invert_yaxis()
    ax.set_xlabel("-log10 p (score and step tests combined)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    _save(fig, os.path.join(out_dir, "ranking.png"))
    def cell(value, fmt):
        return "" if value is None else format(value, fmt)

    rows = ""
    for e in result["ranking"]:
        refit_mse = None if e["refit"] is None else e["refit"]["mse"]
        step = e.get("step") or {}
        rows += (f"<tr><td>{html.escape(e['effect'])}</td><td>{cell(e['statistic'], '.3g')}</td>"
                 f"<td>{cell(e.get('p_value_score', e['p_value']), '.2g')}</td>"
                 f"<td>{html.escape(step.get('step', ''))}</td><td>{cell(step.get('p_value'), '.2g')}</td>"
                 f"<td>{cell((e.get('step_3d') or {}).get('p_value'), '.2g')}</td>"
                 f"<td>{cell(e['p_value'], '.2g')}</td><td>{cell(refit_mse, '.4f')}</td>"
                 f"<td>{cell(e['gain'], '.4g')}</td><td>{html.escape(e['explanation'] or '')}</td></tr>")
    parts.append("<h2>What is missing: score tests at each effect's off value, step tests at its moderate strength"
                 "</h2><img src='ranking.png'>"
                 f"<p>{html.escape(result['threshold_rule'])}. {html.escape(result['test'])}.</p>"
                 "<table border=1 cellpadding=3><tr><th>effect</th><th>score T^2</th><th>score p</th><th>step</th>"
                 "<th>step p</th><th>3D step p</th><th>p</th><th>refit MSE</th>"
                 f"<th>gain / parameter</th><th>explanation</th></tr>{rows}</table>")
    # history: the best-of-K errors on these images, one column per model version (a diagnosed preset), its
    # refits beside it; the versions joined by a line (the training batches' metrics are in diagnosis.json only)
    hist = [h for h in result["history"] if h.get("mse") is not None and h["source"] != TRAINING_SOURCE]
    columns, x, beside = [], [], 0  # beside: refits already placed in the current column
    for h in hist:
        if h["source"] != "diagnose refit" or not columns:
            columns.append(h["model"])
            beside = 0
        if h["source"] == "diagnose refit":
            x.append(len(columns) - 1 + 0.25 + 0.1 * beside)
            beside += 1
        else:
            x.append(len(columns) - 1)
    fig = _figure((6.4, 3.4))
    ax = fig.add_subplot(1, 1, 1)
    versions = [(xx, h) for xx, h in zip(x, hist) if h["source"] != "diagnose refit"]
    refits = [(xx, h) for xx, h in zip(x, hist) if h["source"] == "diagnose refit"]
    ax.plot([xx for xx, _ in versions], [h["mse"] for _, h in versions], "o-", color="C0",
            label="best-of-K MSE, model versions")
    ax.plot([xx for xx, _ in refits], [h["mse"] for _, h in refits], "o", mfc="none", color="C0",
            label="its refits (one effect each)")
    for xx, h in refits:
        ax.annotate(h["model"].rsplit(" + ", 1)[-1], (xx, h["mse"]), fontsize=6, xytext=(3, 2),
                    textcoords="offset points")
    if any(h.get("dc_error") is not None for h in hist):
        ax2 = ax.twinx()
        ax2.plot([xx for xx, h in versions], [np.nan if h.get("dc_error") is None else h["dc_error"]
                                              for _, h in versions], "s--", color="C1", label="|dDC|, versions")
        ax2.set_ylabel("|dDC|")
        ax2.legend(fontsize=7, loc="lower right", bbox_to_anchor=(1.0, 1.0), frameon=False)
    ax.set_xticks(range(len(columns)))
    ax.set_xticklabels(columns, rotation=10, fontsize=7, ha="right")
    ax.set_xlim(-0.4, max(len(columns) - 1, 0) + 0.9)
    ax.set_ylabel("MSE")
    ax.legend(fontsize=7, loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=2, frameon=False)
    fig.tight_layout()
    _save(fig, os.path.join(out_dir, "history.png"))
    fell = [h for h in hist if h["source"] == "diagnose refit" and "report" not in h and b is not None
            and h["mse"] < b["mse"]]
    here = [h for h in hist if "report" not in h and h["source"] == "diagnose refit"]
    words = ("The error fell with " + ", ".join(h["model"] for h in fell) if fell else
             "No refit lowered the best-of-K MSE." if here else "No refit was run.")
    if len(versions) > 1:
        first, last = versions[0][1], versions[-1][1]
        words += (f" Across the {len(versions)} model versions diagnosed on these images the best-of-K MSE went "
                  f"{first['mse']:.4f} ({first['model']}) -> {last['mse']:.4f} ({last['model']})"
                  + (": it fell." if last["mse"] < first["mse"] else ": it did not fall."))
    parts.append(f"<h2>Model history</h2><img src='history.png'><p>{html.escape(words)}</p>")
    text = "<!doctype html><meta charset='utf-8'><title>drapelab diagnosis</title><body style='font-family:sans-serif'>" \
           + "\n".join(parts) + "</body>\n"

    def write(tmp):
        with open(tmp, "w") as fh:
            fh.write(text)
    measure._atomic_write(os.path.join(out_dir, "index.html"), "report", ".html", write)
