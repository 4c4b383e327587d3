"""Up-front estimates of a job's time and memory, so that a job that cannot fit is refused before it runs.

Time (fit --time-budget T covers the whole job: set-up, epochs, drape calibration, writing):
    The drape calibration (infer.calibrate_preset) drapes sets of `draws` posterior draws; a set costs
    e = ceil(draws / lanes) x (one round of `lanes` drapes in parallel), measured up front by draping one such
    round on the calibration mesh (a dynamic rollout's cost does not depend on the table: a fixed number of
    steps, each one factorisation). It needs at least N_min = 3 + iterations + 2 sets (the mean drape
    coefficient and the slope at the fit, the secant steps, the slope at the result) and at most
    N_full = N_min + 2 per node-search step + 2 for the refinement + iterations + 2 (the node search).
    The calibration is given min(N_full e, max(N_min e, calibration_share x T)) (fit.json
    time_budget.calibration_share); the epochs get the rest. A fit without calibration times one drape on its own
    mesh instead (N_min = N_full = 0). A budget below set-up + N_min e + the scale search
    + one epoch (the last two estimated from the measured drape, scaled by vertex count) is refused with those
    figures and a suggested budget 10 % above that minimum (drape times vary by about that between runs).
    At run time only the calibration's first 3 sets are unconditional; every later set is made only if it and the
    sets it needs after it still fit at the longest set so far (else the secant steps stop and the slope at the
    fit's scale is reused), so drapes that get slower during the job (a shared machine) cost accuracy, not time.
    fit --init keeps back START_GUARD_MARGIN x what its start guard needs (two evaluations of start_guard.draws
    draws, estimated from the same measured drapes) from the epochs, as far as they can spare it; the guard runs
    on the draws whose rounds fit in the time left with START_GUARD_RUN_MARGIN to spare (fewer when it must).
    The epochs stop when the next would not finish in their share (predicted by
    the longest epoch so far). The job
    thus ends by max(T + the last epoch, end of epochs + the first 3 sets) + the last set.
Memory:
    A recorded rollout keeps one sparse Cholesky factor per step up to factor_memory_mb (sim.ClothModel.simulate);
    with a contact effect (disk_contact, self_contact: linearised contact steps) one per iteration, up to
    CONTACT_FACTOR_MEMORY_SCALE x factor_memory_mb (RolloutOptions::contact_factor_memory_scale), at most
    CONTACT_ITERATIONS_PER_STEP iterations per step assumed;
    FACTOR_BYTES_PER_VERTEX is an upper bound of a factor's size per vertex measured on circle1..5 (10.2 MB on
    circle3, 35.3 MB on circle5: docs/performance.md). A fit keeps, per Monte Carlo lane, one recorded rollout
    (factors + the rollout's states); per image a float64 mask, and per epoch a soft image, its gradient and a
    hard image for every (sample, image) pair. An evaluation keeps every draw's bending tables, positions and hard
    image. A job estimated above MEMORY_FRACTION of the machine's physical memory is refused with the estimate.
"""
import math
import os
import time

from ._native import InputError

FACTOR_BYTES_PER_VERTEX = 5.0e3      # bytes of one kept Cholesky factor per vertex (measured 3.8-4.7 KB, circle3-5)
DEFAULT_FACTOR_MEMORY_MB = 1024.0    # sim.ClothModel.simulate's default budget for kept factors
CONTACT_FACTOR_MEMORY_SCALE = 1.6     # native RolloutOptions::contact_factor_memory_scale (kept factors with contact)
CONTACT_ITERATIONS_PER_STEP = 1.7     # linearised contact iterations per step (circle3, seeds 0-5: 1.27-1.68)
MODEL_BYTES_PER_VERTEX = 20.0e3      # a model, its solver workspace and one drape's vectors, per vertex (generous)
MEMORY_FRACTION = 0.8                # of physical memory: leaves room for the OS and Blender's own scene
EPOCH_DRAPE_FACTOR = 1.5             # an epoch's drape (recorded rollout + adjoint) / an unrecorded rollout
DEFAULT_CALIBRATION_SHARE = 0.5      # fit.json time_budget.calibration_share when absent
START_GUARD_MARGIN = 1.25            # fit --init's start guard: kept back x its estimate (it runs when the estimate
#                                      is left: epochs that end a little past their share must not skip it)
START_GUARD_RUN_MARGIN = 1.1         # ... and runs on the draws whose rounds fit in the time left with this to spare
#                                      (drape times vary by about 10 % between runs: the refused budget's margin too)


def physical_memory_bytes():
    """The machine's physical memory in bytes (None when the platform does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(estimate_bytes, what, advice):
    """Raises InputError when `estimate_bytes` exceeds MEMORY_FRACTION of physical memory, naming the job,
    the estimate and what to change. Returns the estimate."""
    total = physical_memory_bytes()
    if total is not None and estimate_bytes > MEMORY_FRACTION * total:
        raise InputError(f"{what} would need about {estimate_bytes / 2 ** 30:.1f} GB of memory, more than "
                         f"{MEMORY_FRACTION:.0%} of this machine's {total / 2 ** 30:.1f} GB; {advice}")
    return estimate_bytes


def rollout_bytes(vertices, steps, record=True, factor_memory_mb=DEFAULT_FACTOR_MEMORY_MB, contact=False):
    """About the memory of one model and one rollout on a mesh of `vertices` vertices (recorded: the kept factors,
    capped at factor_memory_mb, and per step the state x, v and the step's solution). contact: the model has a
    contact effect (linearised contact steps keep a factor and two vectors per iteration, within
    CONTACT_FACTOR_MEMORY_SCALE x factor_memory_mb)."""
    model = MODEL_BYTES_PER_VERTEX * vertices
    if not record:
        return model
    factors_kept, cap, vectors = steps, factor_memory_mb * 2 ** 20, 3
    if contact:
        factors_kept = steps * CONTACT_ITERATIONS_PER_STEP
        cap *= CONTACT_FACTOR_MEMORY_SCALE
        vectors += 2 * CONTACT_ITERATIONS_PER_STEP  # each iteration's x and move
    factors = min(factors_kept * FACTOR_BYTES_PER_VERTEX * vertices, cap)
    return model + factors + steps * vectors * 3 * vertices * 8


def fit_memory_bytes(vertices, lanes, steps, images, image_pixels, samples, contact=False):
    """About the peak memory of a fit: `lanes` recorded rollouts, the image masks, and per epoch three float64
    images for each of samples x images drapes (contact: see rollout_bytes)."""
    return (lanes * rollout_bytes(vertices, steps, contact=contact) + images * image_pixels * 8
            + samples * images * 3 * image_pixels * 8)


def evaluate_memory_bytes(vertices, bending_edges, lanes, draws, images, image_pixels):
    """About the peak memory of an evaluation: every draw's bending tables (15 per edge), positions and hard image,
    the masks, and one unrecorded model per lane."""
    return (lanes * rollout_bytes(vertices, 1, record=False)
            + draws * (bending_edges * 15 * 8 + vertices * 3 * 8 + image_pixels * 8) + images * image_pixels * 8)


def calibration_sets(calibration):
    """(N_min, N_full): the fewest and the most sets of drapes calibrate_preset makes with these fit.json
    calibration settings (see the module doc; the node search only when enabled)."""
    iterations = int(calibration.get("iterations", 2))
    minimum = 3 + iterations + 2
    search = calibration.get("node_search") or {}
    if not search.get("enabled", False):
        return minimum, minimum
    steps = max(int(search.get("max_log2", 0)), -int(search.get("min_log2", 0)))
    full = minimum + 2 * steps + (2 if search.get("refine", False) else 0) + iterations + 2
    return minimum, full


class FitPlan:
    """How a fit's time budget is split (all in seconds from the start of the job)."""

    def __init__(self, total, setup, set_seconds, sets_min, sets_full, share, drape_estimate, scale_drapes,
                 epoch_drapes, start_guard=0.0):
        self.total = float(total)
        self.setup = float(setup)              # spent before the plan (loading, the timed round of drapes)
        self.set_seconds = float(set_seconds)  # one set of calibration drapes
        self.sets_min, self.sets_full = int(sets_min), int(sets_full)
        self.calibration_min = self.sets_min * self.set_seconds
        self.drape_estimate = float(drape_estimate)
        self.scale_search = scale_drapes * drape_estimate
        self.first_epoch = epoch_drapes * drape_estimate * EPOCH_DRAPE_FACTOR
        self.minimum = self.setup + self.calibration_min + self.scale_search + self.first_epoch
        room = self.total - self.setup - self.scale_search - self.first_epoch
        self.calibration = min(self.sets_full * self.set_seconds, max(self.calibration_min, share * self.total), room)
        # fit --init's start guard (its start and its end evaluated on the same draws): what it is estimated to
        # need (start_guard_estimate), kept back from the epochs as far as they can spare it; at run time it runs
        # only when the time left covers its estimate
        self.start_guard_estimate = float(start_guard)
        self.start_guard = min(START_GUARD_MARGIN * self.start_guard_estimate, max(0.0, room - self.calibration))
        self.epochs = self.total - self.setup - self.calibration - self.start_guard

    def check(self):
        """Raises InputError (with attribute minimum_s, the budget suggested) when the budget is below the minimum."""
        if self.total >= self.minimum:
            return self
        suggested = math.ceil(self.minimum * 1.1)
        if self.sets_min:
            e = InputError(
                f"time_budget: {self.total:g} s is too small: the drape calibration alone needs about "
                f"{self.calibration_min:.0f} s ({self.sets_min} sets of drapes of {self.set_seconds:.1f} s measured), "
                f"set-up {self.setup:.0f} s, the scale search and a first epoch about "
                f"{self.scale_search + self.first_epoch:.0f} s; use a time budget >= {suggested:d} s, "
                f"or switch the calibration off (fit --no-calibration, fit.json calibration.enabled false)")
        else:
            e = InputError(
                f"time_budget: {self.total:g} s is too small: set-up {self.setup:.0f} s, the scale search and a first "
                f"epoch about {self.scale_search + self.first_epoch:.0f} s (a drape measured at "
                f"{self.drape_estimate:.2f} s); use a time budget >= {suggested:d} s")
        e.minimum_s = suggested
        raise e

    def as_dict(self):
        return {"total_s": self.total, "setup_s": self.setup, "epochs_s": self.epochs,
                "calibration_s": self.calibration, "calibration_set_s": self.set_seconds,
                "calibration_sets": [self.sets_min, self.sets_full], "minimum_s": self.minimum,
                "start_guard_s": self.start_guard}


def check_time_budget(time_budget):
    """A time budget in seconds (None: none), refused unless a finite number > 0."""
    if time_budget is None:
        return None
    try:
        t = float(time_budget)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"time_budget: expected a number of seconds, got {time_budget!r}") from None
    if not (math.isfinite(t) and t > 0):
        raise InputError(f"time_budget: must be a finite number of seconds > 0, got {time_budget!r}")
    return t


class Deadline:
    """A point in time (time.monotonic) and how much of it is left."""

    def __init__(self, seconds, start=None):
        self.start = time.monotonic() if start is None else start
        self.end = self.start + seconds

    def left(self):
        return self.end - time.monotonic()
