"""Bayesian fitting of a fabric's bending stiffness from Cusick silhouettes: HOMO, HETER and BDP.

What is learned (and why): the bending table B (3 x 5, N m), in log space. The silhouette of a Cusick drape is
governed by bending against gravity; membrane stretching changes it by well under a pixel (the paper froze
stretching for the same reason), so the stretching table stays at its starting value (recorded in the
preset). Log space makes every sample positive (no clamping), makes one learning rate fit entries that span
decades (1e-5 .. 1e-4 N m), and turns the multiplicative sample-to-sample variation of a fabric into an
additive Gaussian.

Models (the paper's):
    homo   one deterministic table:          log B_w = mu                     for every bending edge w
    heter  one deterministic table per edge:  log B_w = mu_w
    bdp    mean-field Gaussian, per element:  log B_w = mu + softplus(eta) * eps_w,  eps_w ~ N(0, I)

Forward model (fit.json "forward"): "dynamic" = the paper's 100-step rollout from the flat state and its adjoint
(default: the same forward as evaluation, no dependence on the optimisation path); "static" = Newton to
equilibrium warm-started from the previous epoch (cheaper per epoch, path dependent).

Loss (negative ELBO, Monte Carlo over S samples per epoch, stated in fit.json):
    L = mean_s [ mean_pixels (I_hat_s - I)^2 / (2 sigma_obs^2) + (DC_s - DC)^2 / (2 sigma_dc^2) ] + kl_weight * KL(q || p)
where the first term is the per-pixel Gaussian negative log-likelihood averaged over pixels (constant
dropped; sigma_obs from fit.json); the second is a Gaussian likelihood of the drape coefficient (the soft
silhouette's area, rotation-free): pixel MSE on raw silhouettes mostly measures where the folds happen to
fall (the dataset's noise floor), and alone it left the fitted drape coefficient 0.04-0.08 off. sigma_dc
(fit.json) weights both so that a deviation at the measured noise floor costs the same in each:
sigma_dc = dc_floor * sigma_obs / sqrt(mse_floor), with dc_floor 0.031 (sd of the drape coefficient across
re-drapes of one sample) and mse_floor 0.042 (pixel MSE between re-drapes), fabrics 1-5 of the dataset's
README. KL is the closed form for the 15 table entries between
q = N(mu, softplus(eta)^2) and the isotropic prior p = N(mu0, s0^2) (mu0 = the starting table, s0 from
fit.json), i.e. log q - log p averaged over elements as in the paper's released code. HOMO and HETER are
fitted as MAP point estimates under the same prior (the term is -log p up to a constant; averaged over
elements for HETER): the paper's deterministic baselines are maximum likelihood, but one silhouette does
not pin 15 free entries and the unregularised tables wander far (measured: entries spread over 3 decades).
Gradients: soft-render VJP -> drape adjoint -> dL/dB_w -> reparameterisation (dL/dmu = sum_w g_w, dL/deta = sum_w g_w eps_w sigmoid(eta), g_w = B_w dL/dB_w).

Placement noise (fit.json "placement_noise"): a real drape is stochastic (the same sample draped again puts
its folds elsewhere). BDP draws, in training and in evaluation, start from the flat state with a small random
vertical velocity field v_z = a * ((r - r_disk) / (R - r_disk))^2 * sum_k (c_k cos k theta + s_k sin k theta),
k = 1..K, c, s ~ N(0, 1/K): the posterior predictive then covers fold placements, not one. HOMO and HETER stay
deterministic (the paper's baselines).

Drape calibration (bdp, fit.json "calibration"; calibrate_preset): the fit ends by scaling the mean table so that
the predictive mean drape coefficient equals the training images', and by adding a per-draw global log factor
that spreads the predictive by the measured scatter of a fabric's drapes (calibrated on fabrics 11-20). The
test drapes of a fabric are other specimens and re-drapes: without it the 90 % interval covered 22 % of them.

The numerical core is native (native/src/infer, reached through drapelab.variational): the families above as
types (parameter blocks, draws from noise, the chain rule, the prior), the fitted effects' block, the ELBO
assembly with its gradient clipping, Adam and the clip rule, and the sample loop (infer/sample_loop.hpp): each
epoch's draws (drape, soft render, data term, observation and adjoint) and the start searches' drapes on native
threads, one lane per worker, cancel polled at every solver step. This module keeps the configuration, the
draws' noise (numpy streams, below), the start searches' choice, checkpoints and presets.

A fit is a job: progress callback per epoch, cancel (threading.Event), a checkpoint after every epoch
(atomic JSON, resumable, bit-identical continuation: the noise of epoch k sample s is drawn from
default_rng([seed, k, s])), a time budget or an epoch count. Monte Carlo samples run on native threads (the
loop releases the GIL); the same seed gives the same result whatever the thread count (each Monte Carlo
slot keeps its own warm start). A resumed fit restarts its warm starts from the flat drape.
"""
import copy
import datetime
import hashlib
import json
import math
import os
import time

import numpy as np

from . import budget, fit_effects, measure, render, sim, tables, variational
from ._native import Cancelled, InputError, SolverError, native

__all__ = ["MODELS", "load_config", "FitJob", "fit", "load_preset", "write_preset", "sample_bend_tables",
           "kl_divergence", "evaluate", "calibrate_preset", "PRESET_SCHEMA_VERSION"]

MODELS = ("homo", "heter", "bdp")
PRESET_SCHEMA_VERSION = 2  # 2: active_effects carries the effects' values (1: always empty); 1 is migrated on load
CONFIG_PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "config", "fit.json")
MAX_PLAUSIBLE_DENSITY = 5.0  # kg/m^2: heavier than any woven or knitted fabric by far
BEND_SHAPE = tables.BEND_SHAPE
# What a configuration without these fit.json entries gets (fit.json sets them all; see its comments).
DEFAULT_MAX_THREADS = 2  # fit.json max_threads: Monte Carlo lanes by default (the reference machine has 2 cores)
DEFAULT_EFFECT_SETTINGS = {"learning_rate": 0.1, "eta_learning_rate": 0.05, "init_std": 0.1, "prior_weight": 1.0,
                           "start_search_drapes": 1}
START_SEARCH_STREAM = 3  # the effects' start search's placements: default_rng([seed, 0, drape, 3]), apart from an
#                          epoch's streams [seed, epoch, sample(, 1 | 2)] (FitJob._start_velocities)
DEFAULT_GRADIENT_CLIP = {"factor": 0.0, "window": 10, "min_epochs": 3}
INIT_MIN_STD = 1e-4  # fit --init: a preset's posterior sd of 0 (a point estimate) starts a bdp sd here
DEFAULT_INIT_PRESET = {"learning_rate_factor": 1.0}  # fit.json "init_preset" when it does not set it
DEFAULT_START_GUARD = {"enabled": False, "draws": 8}  # fit.json init_preset.start_guard when it does not set it
START_GUARD_SEED_OFFSET = 5000  # the start guard's draws: evaluate(seed + this), apart from the fit's own streams


def load_config(path=None):
    path = path or CONFIG_PATH
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: cannot read the fit configuration: {e}") from None


def softplus(x):
    return np.logaddexp(0.0, x)


def inverse_softplus(y):
    return np.log(np.expm1(y))


def kl_divergence(mu, sigma, mu0, sigma0):
    """KL(N(mu, sigma^2) || N(mu0, sigma0^2)) summed over entries, and its gradients (d/dmu, d/dsigma) (native)."""
    return variational.kl_divergence(mu, sigma, mu0, sigma0)


def default_threads(config=None, threads=None):
    """Monte Carlo lanes: `threads`, else the cores up to fit.json max_threads."""
    cap = int((config or {}).get("max_threads", DEFAULT_MAX_THREADS))
    return max(1, int(threads or min(os.cpu_count() or 1, cap)))


def effect_settings(config):
    """fit.json "effects" with DEFAULT_EFFECT_SETTINGS for what it does not set."""
    return dict(DEFAULT_EFFECT_SETTINGS, **(config.get("effects") or {}))


def check_density(density):
    try:
        d = float(density)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"density: expected a number in kg/m^2, got {density!r}") from None
    if not math.isfinite(d) or d <= 0:
        raise InputError(f"density: must be > 0 kg/m^2, got {density!r}")
    if d > MAX_PLAUSIBLE_DENSITY:
        raise InputError(f"density: {d} kg/m^2 is not a fabric's area density (expected well below "
                         f"{MAX_PLAUSIBLE_DENSITY} kg/m^2; fabrics weigh 0.05-0.5 kg/m^2): wrong unit?")
    return d


def check_optional_int(value, name, minimum):
    """An integer argument (None: the default) >= minimum, else InputError naming it."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise InputError(f"{name}: expected an integer >= {minimum}, got {value!r}")
    return int(value)


def sample_bend_tables(model_kind, theta, num_edges, noise=None):
    """Bending tables (E, 3, 5) in N m (or (3, 5) for homo) for parameters theta and standard-normal noise
    (None: zero). model_kind: a model name or a variational.Family."""
    family = model_kind if isinstance(model_kind, variational.Family) else variational.Family(model_kind)
    return family.tables(theta, num_edges, noise)


def placement_velocities(rest, rng, amplitude, modes, support_radius=0.09, specimen_radius=0.15):
    """Initial velocities (V, 3) of one random placement: vertical, zero on the support disk (see module doc)."""
    rest = np.asarray(rest, dtype=float)
    v = np.zeros_like(rest)
    if amplitude <= 0 or modes < 1:
        return v
    r = np.hypot(rest[:, 0], rest[:, 1])
    theta = np.arctan2(rest[:, 1], rest[:, 0])
    radial = np.clip((r - support_radius) / (specimen_radius - support_radius), 0.0, None) ** 2
    c = rng.standard_normal((2, modes)) / math.sqrt(modes)
    k = np.arange(1, modes + 1)[:, None]
    v[:, 2] = amplitude * radial * (c[0] @ np.cos(k * theta) + c[1] @ np.sin(k * theta))
    return v


def data_term(image, obs, sigma_obs, sigma_dc, dc_bias=0.0):
    """The data term of the loss for one (soft or hard) silhouette against one observation, and its gradient
    per pixel: mean_pixels (I_hat - I)^2 / (2 sigma_obs^2) + (DC_hat - b - DC)^2 / (2 sigma_dc^2) (sigma_dc 0: no
    DC term), b = dc_bias: the soft silhouette's drape coefficient minus the hard one's (a constant; FitJob
    estimates it, see FitJob.estimate_dc_bias; 0 for hard silhouettes). Native (infer/sample_loop.hpp), the
    function the fit's sample loop evaluates."""
    target = getattr(obs, "target", None)
    if target is None:  # any object with a hard `mask` (and `dc`, `calibration` for the DC term)
        target = native.infer.SilhouetteTarget(np.ascontiguousarray(obs.mask, dtype=np.float64),
                                               float(getattr(obs, "dc", 0.0)))
    value, g_image = native.infer.data_term(np.ascontiguousarray(image, dtype=np.float64), target,
                                            _data_settings(obs, sigma_obs, sigma_dc, dc_bias))
    return float(value), np.asarray(g_image)


def _data_settings(obs, sigma_obs, sigma_dc, dc_bias=0.0):
    if sigma_dc and not hasattr(obs, "calibration"):
        raise InputError("data term: the drape-coefficient term needs the observation's calibration and dc")
    px = obs.calibration["px_per_m"] if hasattr(obs, "calibration") else measure.DATASET_PX_PER_M
    return native.infer.DataTermSettings(float(sigma_obs), float(sigma_dc or 0.0), float(dc_bias or 0.0), float(px))


class _Observation:
    def __init__(self, path, calibration):
        self.path = path
        sil = measure.load_silhouette(path, calibration)
        self.mask = np.asarray(sil.mask, dtype=np.float64)
        c = sil.calibration
        self.calibration = {"px_per_m": float(c.px_per_m), "centre_px": [float(c.cx), float(c.cy)]}
        self.dc = float(measure.drape_coefficient(self.mask, c.px_per_m))
        self.target = native.infer.SilhouetteTarget(self.mask, self.dc)
        nodes = measure.analyse_nodes(measure.r_theta(self.mask, c))
        self.nodes = int(nodes.count)
        self.amplitude = float(nodes.amplitude_m)
        with open(path, "rb") as f:
            self.sha256 = hashlib.sha256(f.read()).hexdigest()


def _camera_for(kind, calibration, shape):
    h, w = shape
    if kind == "ortho":
        return render.orthographic_camera(px_per_m=calibration["px_per_m"], centre=tuple(calibration["centre_px"]),
                                          size=(w, h))
    if kind == "perspective":
        return render.perspective_camera(size=(w, h))
    raise InputError(f"camera: expected 'ortho' or 'perspective', got {kind!r}")


class _Worker:
    """One Monte Carlo lane's model and renderer (the epoch's draws run in the native sample loop, one lane per
    worker; the start searches use the workers' models directly)."""

    def __init__(self, mesh, heterogeneous, density, config, camera, plan=None, px_per_m=720.0):
        plan = plan or fit_effects.EffectPlan()
        self.model = sim.ClothModel(mesh, heterogeneous=heterogeneous, density=density, effects=plan.values(),
                                    px_per_m=px_per_m)
        self.renderer = render.SoftRenderer(camera, sigma=config["render_sigma_px"])
        self.faces = self.model.faces


def _native_loop(models, camera, static, dynamic, statics, render_sigma_px=1.0):
    """The native sample loop (infer/sample_loop.hpp) on `models` (ClothModel, one lane each): `static` forward or
    not, `dynamic` the rollout settings (fit.json "dynamic"), `statics` the Newton settings (fit.json "static");
    missing settings take sim's defaults."""
    return native.infer.SampleLoop(
        [m.native for m in models], camera, render_sigma_px=float(render_sigma_px), static=bool(static),
        time_step=float(dynamic.get("time_step", sim.DEFAULT_TIME_STEP)),
        steps=int(dynamic.get("steps", sim.DEFAULT_STEPS)),
        max_speed=float(dynamic.get("max_speed", sim.DEFAULT_MAX_SPEED)),
        force_tolerance=float(statics.get("force_tolerance", sim.DEFAULT_FORCE_TOLERANCE)),
        max_iterations=int(statics.get("max_iterations", sim.DEFAULT_MAX_ITERATIONS)))


def _observed(model, x, params):
    """The positions the renderer sees (the active effects' measurement transforms; x when none)."""
    return model.observe(x, params) if model.has_observation else x


def _observed_backward(model, x, params, g_observed, cancel_event=None, alternatives=None):
    """Parameter gradients (a split dict) of a loss of the rendered positions _observed(model, x, params), given
    its gradient there: back through the measurement transforms (camera, offset), then the drape's adjoint.
    `alternatives` (parameter vectors at which the rollout and the measurement's position map are the same, as
    ClothModel.backward takes them): a list of split dicts, at `params` and then at each alternative."""
    if not model.has_observation:
        return model.backward(g_observed, cancel_event=cancel_event, alternatives=alternatives)
    g_x, g_direct = model.observe_backward(x, params, g_observed, flat=True)
    if alternatives is None:
        return model.split(model.backward(g_x, flat=True, cancel_event=cancel_event) + g_direct)
    gs = model.backward(g_x, flat=True, cancel_event=cancel_event, alternatives=alternatives)
    directs = [g_direct] + [model.observe_backward(x, q, g_observed, flat=True)[1] for q in alternatives]
    return [model.split(g + d) for g, d in zip(gs, directs)]


class FitJob:
    """A fit of one model to one or more silhouettes; run() until done, cancelled or out of time."""

    def __init__(self, images, density, model="bdp", seed=0, config=None, camera="ortho", calibration=None,
                 mesh_level=None, template_dir=None, threads=None, init_bend=None, init_stretch=None, effects=None):
        if model not in MODELS:
            raise InputError(f"model: expected one of {MODELS}, got {model!r}")
        if not images:
            raise InputError("images: give at least one Cusick silhouette")
        self.kind = model
        self.family = variational.Family(model)  # the variational family: parameter blocks, draws, prior
        self.density = check_density(density)
        self.seed = int(seed)
        self.config = config or load_config()
        self.observations = [_Observation(p, calibration) for p in images]
        shape = self.observations[0].mask.shape
        for o in self.observations:
            if o.mask.shape != shape:
                raise InputError(f"{o.path}: image size {o.mask.shape} differs from {self.observations[0].path} {shape}")
        self.camera_kind = camera
        self.camera = _camera_for(camera, self.observations[0].calibration, shape)
        level = mesh_level or self.config["mesh_level"]
        self.mesh_level = level
        self.mesh = sim.cusick_specimen(level, template_dir=template_dir)
        self.stretch = np.array(init_stretch if init_stretch is not None else tables.preset(self.config["init"]["stretch"]).stretch,
                                dtype=float)
        if not self.config["init"].get("stretch_strain_dependent", True):
            # Every row = the small-strain row: a linear orthotropic membrane. The published tables soften
            # 3-5x with strain, and the step matrix's geometric term (secant stress) then underestimates the
            # true stress enough to make the h = 0.05 s rollout diverge for limp fabrics (measured: bending
            # scaled by 1/4..1/16 diverges at step 6-8 with the published table, not with this one).
            self.stretch[1:] = self.stretch[0]
        bend0 = np.asarray(init_bend if init_bend is not None else tables.preset(self.config["init"]["bend"]).bend, dtype=float)
        if bend0.shape != BEND_SHAPE or not np.all(np.isfinite(bend0)) or np.any(bend0 <= 0):
            raise InputError(f"init_bend: expected a positive finite {BEND_SHAPE} table")
        self.log_bend0 = np.log(bend0)
        prior = self.config["prior"]
        self.prior_mu = self.log_bend0.copy() if prior["log_bend_mean"] == "start" else np.full(BEND_SHAPE, float(prior["log_bend_mean"]))
        self.prior_sigma = float(prior["log_bend_std"])
        self.sigma_obs = float(self.config["sigma_obs"])
        self.sigma_dc = float(self.config.get("sigma_dc") or 0.0)
        pn = self.config.get("placement_noise") or {}
        self.placement = ((float(pn.get("velocity_m_s", 0.0)), int(pn.get("angular_modes", 0))) if self.family.stochastic
                          else (0.0, 0))
        self.threads = default_threads(self.config, threads)
        self.samples = int(self.config["samples_per_epoch"]) if self.family.stochastic else 1
        heterogeneous = self.family.per_element
        lanes = min(self.threads, max(self.samples, len(self.observations)))
        self.plan = fit_effects.EffectPlan(effects)
        self.workers = [_Worker(self.mesh, heterogeneous, self.density, self.config, self.camera,
                                self.plan, self.observations[0].calibration["px_per_m"]) for _ in range(lanes)]
        self.num_edges = self.workers[0].model.num_bending_edges
        self.theta = self.family.initial(self.log_bend0, self.num_edges, float(self.config["init"]["bdp_std"]))
        # Fitted effect parameters (fit_effects.EffectPlan): their means (MAP values for homo/heter) start at
        # the off values, a bdp posterior sd at fit.json effects.init_std x the prior scale; Adam's step size is
        # effects.learning_rate x the registry's moderate strength (the parameters carry units).
        self.learning_rates = {k: float(v) for k, v in self.config["learning_rates"][model].items()}
        self.effect_block = variational.effect_block(self.plan)  # None without fitted effects
        if self.plan.size:
            ecfg = effect_settings(self.config)
            self.theta["effect_mu"] = self.plan.off.copy()
            self.learning_rates["effect_mu"] = float(ecfg["learning_rate"]) * self.plan.moderate
            if self.family.stochastic:
                self.theta["effect_eta"] = inverse_softplus(float(ecfg["init_std"]) * self.plan.prior_scale)
                self.learning_rates["effect_eta"] = float(ecfg["eta_learning_rate"])
        self.effect_start = None  # result of the effects' start search
        bias = self.config.get("dc_soft_bias", "estimate")
        self.dc_bias = None if bias == "estimate" else float(bias)  # None: estimated when run() starts
        self.adam = {k: {"m": np.zeros_like(v), "v": np.zeros_like(v)} for k, v in self.theta.items()}
        # The epoch's draws run natively on one lane per worker; static mode's warm starts (Monte Carlo slot ->
        # last equilibrium) live there (the `warm` property).
        self.loop = _native_loop([w.model for w in self.workers], self.camera, self.config["forward"] == "static",
                                 self.config["dynamic"], self.config["static"], self.config["render_sigma_px"])
        self.previous_theta = None  # before the last Adam step (undone if the next drape fails)
        self.scale = None  # result of the initial scale search
        self.lr_scale = 1.0
        self.epoch = 0
        self.history = []
        self.elapsed = 0.0
        self.start_metrics = None

    # -- objective
    def noise(self, epoch, sample):
        rng = np.random.default_rng([self.seed, epoch, sample])
        return rng.standard_normal((self.num_edges,) + BEND_SHAPE)

    def effect_noise(self, epoch, sample):
        """Standard-normal noise of this epoch's sample for the fitted effects' bdp posterior (its own stream)."""
        rng = np.random.default_rng([self.seed, epoch, sample, 2])
        return rng.standard_normal(self.plan.size)

    def effect_draw(self, theta, epoch, sample):
        """The fitted effect values of one sample (clipped to their bounds), the mask of those inside the bounds
        (the gradient flows only there), and the noise (bdp; None otherwise)."""
        if not self.plan.size:
            return None, None, None
        eps = self.effect_noise(epoch, sample) if self.family.stochastic else None
        clipped, inside = variational.effect_draw(self.effect_block, theta, eps)
        return clipped, inside, eps

    def placement_noise(self, epoch, sample):
        """Initial velocities of this epoch's sample (None: no placement noise), from its own seeded stream."""
        if self.placement[0] <= 0:
            return None
        rng = np.random.default_rng([self.seed, epoch, sample, 1])
        return placement_velocities(self.workers[0].model.rest_positions, rng, *self.placement)

    def objective(self, theta, epoch, cancel_event=None, clip=None):
        """Loss terms and gradient dict for theta at this epoch's noise (deterministic given the seed).

        terms["grad_norm"] is the norm of the data term's Monte Carlo gradient (all blocks together); with
        `clip` (a norm) that gradient is scaled down to at most `clip` (terms["clip"] = the factor applied)
        before the prior/KL gradient, which is exact, is added."""
        model = self.workers[0].model
        draws, meta = [], []
        for s in range(self.samples):
            noise = self.noise(epoch, s) if self.family.stochastic else None
            v0 = self.placement_noise(epoch, s)
            effect = self.effect_draw(theta, epoch, s)
            bend = self.family.tables(theta, self.num_edges, noise)
            p = model.parameters(stretch=self.stretch, bend=bend,
                                 effects=self.plan.values(effect[0]) if effect[0] is not None else None)
            for k in range(len(self.observations)):
                # slot = the draw's index: its warm start does not depend on the lane that runs it
                draws.append(native.infer.SampleDraw(p, None if v0 is None else np.ascontiguousarray(v0).ravel(), k,
                                                     len(draws)))
                meta.append((bend, noise, effect))
        sink = sim._progress_sink(None, cancel_event, "fit epoch")
        out = self.loop.run(draws, [o.target for o in self.observations],
                            _data_settings(self.observations[0], self.sigma_obs, self.sigma_dc, self.dc_bias), sink)
        # The ELBO assembly (mean data term, chain rule to theta, clipping, prior) is native (infer/elbo.hpp).
        elbo_draws, images = [], []
        for (data, g_flat, image), (bend, noise, (_, _, eps)) in zip(out, meta):
            g = model.split(g_flat)
            elbo_draws.append(variational.Draw(data, g["bend"], bend, noise,
                                               self.plan.gather(g) if self.plan.size else None, eps))
            images.append(image)
        # The prior: the family's (bdp: KL to N(prior_mu, prior_sigma^2); homo/heter: MAP under it, because one
        # silhouette does not pin 15 free entries and unregularised tables wander to shapes that drape the training
        # image but generalise badly), and N(off, prior_scale^2) per fitted effect parameter (the registry's)
        # weighted by kl_weight x fit.json effects.prior_weight: the pixel likelihood is a mean over pixels
        # (tempered, the paper's), so at full weight the prior dominates a moderate effect (a 0.15 rad tilt was
        # recovered as 0.10 with prior scale 0.15 rad, 0.145 without prior).
        ecfg = effect_settings(self.config)
        terms, grads = variational.assemble_elbo(
            self.family, self.effect_block, theta, elbo_draws, clip, self.prior_mu, self.prior_sigma,
            float(self.config["kl_weight"]), float(ecfg["prior_weight"]))
        terms["images"] = images
        return terms, grads

    @property
    def warm(self):
        """Static mode's warm starts: {Monte Carlo slot: last equilibrium (V, 3)} (a copy)."""
        return {k: np.asarray(v).reshape(-1, 3) for k, v in self.loop.warm_starts.items()}

    @warm.setter
    def warm(self, value):
        self.loop.warm_starts = {int(k): np.ascontiguousarray(v, dtype=np.float64).ravel() for k, v in value.items()}

    def clip_threshold(self):
        """Clipping norm for the next epoch's data gradient: fit.json gradient_clip.factor x the median norm
        of the first `window` accepted epochs (of those recorded so far; None until `min_epochs` are recorded,
        or when switched off). The reference is frozen after `window` epochs: it is the gradient scale of the
        posterior near its start.

        Why: the drape of a draw is exact-differentiable but rough (folds bifurcate), so per-draw gradients
        are heavy-tailed (measured on fabric 1 at the start of a fit: median norm ~10, one draw in ~16 at
        260), and grow by decades as the posterior widens (a 120 s fit, posterior std 0.1 -> 0.4: norms 1e3 to
        2e9 in most epochs, so a running median follows them up). One such draw inflates Adam's second moment
        for ~1/(1 - beta2) epochs and stalls the fit, or kicks it along a meaningless direction."""
        cfg = dict(DEFAULT_GRADIENT_CLIP, **(self.config.get("gradient_clip") or {}))
        norms = [h["grad_norm"] for h in self.history if "rejected" not in h and "grad_norm" in h]
        return variational.clip_threshold(norms, float(cfg["factor"] or 0.0), int(cfg["window"]), int(cfg["min_epochs"]))

    # -- optimisation
    def adam_step(self, grads):
        """One Adam step (native, infer/adam.hpp) at step number epoch + 1; the effect means are projected into
        their bounds."""
        cfg = self.config["adam"]
        self.theta = variational.adam_step(self.theta, grads, self.adam, self.epoch + 1, self.learning_rates,
                                           self.lr_scale, cfg["beta1"], cfg["beta2"], cfg["epsilon"], self.effect_block)

    def metrics(self, images):
        out = []
        for img, o in zip(images, self.observations * (len(images) // len(self.observations))):
            hard = (img >= 0.5).astype(np.float64)
            out.append({"iou": measure.iou(hard, o.mask), "mse": measure.pixel_mse(hard, o.mask)})
        return {"iou": float(np.mean([m["iou"] for m in out])), "mse": float(np.mean([m["mse"] for m in out]))}

    def _start_scores(self, params, velocities, cancel_event=None):
        """The start searches' scores: per parameter vector in `params`, the mean over the training images of the
        best (smallest) data term of its drapes' hard silhouettes, one unrecorded rollout from flat per placement in
        `velocities` (None: at rest); inf where none of its drapes succeed. Natively on the job's lanes
        (infer/sample_loop.hpp, SampleLoop.score)."""
        draws = [native.infer.SampleDraw(p, None if v is None else np.ascontiguousarray(v).ravel())
                 for p in params for v in velocities]
        sink = sim._progress_sink(None, cancel_event, "start search")
        terms = np.asarray(self.loop.score(draws, [o.target for o in self.observations],
                                           _data_settings(self.observations[0], self.sigma_obs, self.sigma_dc), sink))
        terms = terms.reshape(len(params), len(velocities), len(self.observations))
        return [float(np.mean(np.min(t, axis=0))) for t in terms]

    def scale_search(self, cancel_event=None):
        """Initialisation: the one-parameter family start_table * s (s from fit.json init.scale_search) drapes
        most like the training images; theta, and the prior mean, move to the best s. One silhouette pins the
        overall bending scale well (and fabrics differ by decades), so this takes the fit to the right basin
        in a few drapes; the table's shape is then learned by the gradient epochs."""
        factors = self.config["init"].get("scale_search") or []
        if not factors:
            return None
        model = self.workers[0].model
        params = []
        for f in factors:
            bend = np.exp(self.log_bend0) * float(f)
            params.append(model.parameters(stretch=self.stretch, bend=bend if not self.family.per_element else
                                           np.broadcast_to(bend, (self.num_edges,) + BEND_SHAPE)))
        scores = self._start_scores(params, [None], cancel_event)
        best = float(factors[int(np.argmin(scores))])
        shift = np.log(best)
        self.log_bend0 = self.log_bend0 + shift
        self.prior_mu = self.prior_mu + shift
        self.theta["mu"] = self.theta["mu"] + shift
        self.scale = {"factors": list(map(float, factors)), "mse": scores, "chosen": best}
        return self.scale

    def start_search_drapes(self):
        """Drapes each start candidate of the effects' search is scored on: fit.json effects.start_search_drapes
        with placement noise (bdp), else 1 (the deterministic drape from flat)."""
        if self.placement[0] <= 0:
            return 1
        return max(1, int(effect_settings(self.config)["start_search_drapes"]))

    def _start_velocities(self, drapes):
        """The placement velocities of the effects' start search (None per drape without placement noise): the
        same `drapes` placements for every candidate, so that their scores compare like for like, from a stream
        of their own (START_SEARCH_STREAM); one drape is the deterministic drape from flat at rest."""
        if self.placement[0] <= 0 or drapes == 1:
            return [None]
        rest = self.workers[0].model.rest_positions
        return [placement_velocities(rest, np.random.default_rng([self.seed, 0, d, START_SEARCH_STREAM]),
                                     *self.placement)
                for d in range(drapes)]

    def effect_start_search(self, cancel_event=None):
        """Initialisation of the fitted effects: of the plan's start candidates (the off values, and each
        fitted effect's primary parameter at +- its moderate strength), the one whose drapes (mean material) fit
        the training images best; theta's effect means move there. At an off value some parameters have no
        gradient (a tilt's azimuth at zero angle), so the gradient epochs alone could not leave it. With
        placement noise each candidate is scored by the best of start_search_drapes() drapes of the same
        placements per image (best-of-K, as the evaluation judges drapes): one drape without placement noise,
        whose folds fall where the flat rest state puts them whatever the candidate, chose a tilt's opposite
        direction in 2 of 4 synthetic cases, four placement drapes in none (docs/lab/effect-recovery.md)."""
        model = self.workers[0].model
        bend = self.family.tables(self.theta, self.num_edges)
        candidates = self.plan.start_candidates(self.theta["effect_mu"])
        drapes = self.start_search_drapes()
        params = [model.parameters(stretch=self.stretch, bend=bend, effects=self.plan.values(c)) for c in candidates]
        scores = self._start_scores(params, self._start_velocities(drapes), cancel_event)
        best = int(np.argmin(scores))
        self.theta["effect_mu"] = candidates[best].copy()
        self.effect_start = {"parameters": self.plan.names, "candidates": [c.tolist() for c in candidates],
                             "loss": scores, "chosen": candidates[best].tolist(), "drapes": drapes}
        return self.effect_start

    def start_from(self, preset):
        """Starts the fit where a preset left off (fit --init; the material's mean table and the stretching table
        are already the job's start, see init_options): a bdp posterior sd per table entry from a bdp preset, and
        each fitted effect parameter the preset carries at the preset's value (and bdp sd). When every fitted
        effect parameter comes from the preset, the effects' start search is skipped: the preset's values are the
        start (e.g. a diagnosis's refit, chosen on K drapes with placement noise, which the search's one drape
        without it would judge worse)."""
        if "eta" in self.theta and preset["model"] == "bdp":
            self.theta["eta"] = inverse_softplus(np.maximum(np.asarray(preset["posterior"]["bend"]["log_std"],
                                                                       dtype=float), INIT_MIN_STD))
        given = []
        if self.plan.size:
            block = preset.get("active_effects") or {}
            mu = np.asarray(self.theta["effect_mu"], dtype=float).copy()
            for i, (name, p) in enumerate(self.plan.free):
                e = (block.get(name) or {}).get(p["name"])
                if e is None:
                    continue
                mu[i] = float(np.clip(float(e["value"]), self.plan.lower[i], self.plan.upper[i]))
                given.append(self.plan.names[i])
                s = float(e.get("std", 0.0) or 0.0)
                if s > 0 and "effect_eta" in self.theta:
                    self.theta["effect_eta"][i] = inverse_softplus(max(s, INIT_MIN_STD))
            self.theta["effect_mu"] = mu
            if len(given) == self.plan.size:
                self.effect_start = {"parameters": self.plan.names, "candidates": [mu.tolist()],
                                     "chosen": mu.tolist(), "from": "the init preset"}
        return given

    def estimate_dc_bias(self, cancel_event=None):
        """The soft silhouette's drape coefficient minus the hard one's, on the mean drape at the start (after the
        start searches). The soft renderer's 1 px blur puts more coverage outside the boundary than it takes
        inside (measured: ~2 % of the area, +0.02 in drape coefficient on circle1), and the observations'
        drape coefficients are hard; uncorrected, the DC term pulls every fit towards smaller silhouettes and
        against the pixel term (a tilt of 0.15 rad was fitted back to 0). Held constant during the fit, so
        the loss stays exactly differentiable."""
        w = self.workers[0]
        bend = self.family.tables(self.theta, self.num_edges)
        effects = self.plan.values(self.theta["effect_mu"]) if self.plan.size else None
        p = w.model.parameters(stretch=self.stretch, bend=bend, effects=effects)
        x = _observed(w.model, w.model.simulate(p, mode="dynamic", record=False, cancel_event=cancel_event,
                                                **self.config["dynamic"]), p)
        px = self.observations[0].calibration["px_per_m"]
        # the soft silhouette's area is its summed coverage, the hard one's its pixels (the native data term's DC)
        soft = measure.drape_coefficient_from_area(float(np.sum(w.renderer.render(x, w.faces))) / px ** 2)
        hard = measure.drape_coefficient(render.hard_silhouette(self.camera, x, w.faces), px)
        self.dc_bias = float(soft - hard)
        return self.dc_bias

    def run(self, epochs=None, time_budget=None, progress=None, cancel_event=None, checkpoint=None):
        """Runs epochs until `epochs` in total are done or the next epoch would not end within `time_budget`
        seconds of this call (predicted by the longest epoch of this call; the first always starts, and the
        scale search counts). Returns the history."""
        if epochs is None and time_budget is None:
            epochs = int(self.config["default_epochs"])
        if epochs is not None and int(epochs) < 1:
            raise InputError(f"epochs: must be >= 1, got {epochs}")
        time_budget = budget.check_time_budget(time_budget)
        _check_fit_memory(self)
        t0 = time.monotonic()
        longest = 0.0  # the longest epoch of this run (accepted or not): the next one is predicted to take as long
        if self.epoch == 0 and self.scale is None:
            ts = time.monotonic()
            self.scale_search(cancel_event)
            self.elapsed += time.monotonic() - ts
        if self.epoch == 0 and self.plan.size and self.effect_start is None:
            ts = time.monotonic()
            self.effect_start_search(cancel_event)
            self.elapsed += time.monotonic() - ts
        if self.dc_bias is None and self.sigma_dc:
            ts = time.monotonic()
            self.estimate_dc_bias(cancel_event)
            self.elapsed += time.monotonic() - ts
        while True:
            if epochs is not None and self.epoch >= int(epochs):
                break
            if time_budget is not None and time.monotonic() - t0 + longest > time_budget:
                break
            if cancel_event is not None and cancel_event.is_set():
                raise Cancelled()
            te = time.monotonic()
            try:
                terms, grads = self.objective(self.theta, self.epoch, cancel_event, clip=self.clip_threshold())
            except SolverError as e:
                longest = max(longest, time.monotonic() - te)
                # The last step took the tables where a drape fails (diverged rollout, no equilibrium):
                # undo it and halve the learning rate. Nothing to undo before the first step.
                if self.previous_theta is None:
                    raise
                self.theta = {k: v.copy() for k, v in self.previous_theta.items()}
                self.previous_theta = None
                self.lr_scale *= 0.5
                self.loop.forget_warm_starts()
                self.history.append({"epoch": self.epoch, "rejected": str(e), "lr_scale": self.lr_scale})
                continue
            m = self.metrics(terms["images"])
            if self.start_metrics is None:
                self.start_metrics = m
            self.previous_theta = {k: v.copy() for k, v in self.theta.items()}
            self.adam_step(grads)
            self.epoch += 1
            entry = {"epoch": self.epoch, "loss": terms["loss"], "data": terms["data"], "kl": terms["kl"],
                     "iou": m["iou"], "mse": m["mse"], "grad_norm": terms["grad_norm"], "clip": terms["clip"],
                     "seconds": time.monotonic() - te}
            if self.plan.size:  # the fitted effects' means after this epoch's step
                entry["effects"] = dict(zip(self.plan.names, map(float, self.theta["effect_mu"])))
            self.history.append(entry)
            self.elapsed += entry["seconds"]
            longest = max(longest, entry["seconds"])
            if checkpoint:
                self.save_checkpoint(checkpoint)
            if progress:
                progress(dict(entry))
        return self.history

    # -- checkpoints
    def state(self):
        return {"schema": "drapelab-fit-checkpoint", "version": 1, "model": self.kind, "seed": self.seed,
                "epoch": self.epoch, "density": self.density, "mesh_level": self.mesh_level,
                "images": [o.path for o in self.observations],
                "theta": {k: v.tolist() for k, v in self.theta.items()},
                "adam": {k: {"m": s["m"].tolist(), "v": s["v"].tolist()} for k, s in self.adam.items()},
                "history": self.history, "elapsed": self.elapsed, "start_metrics": self.start_metrics,
                "lr_scale": self.lr_scale, "prior_mu": self.prior_mu.tolist(), "log_bend0": self.log_bend0.tolist(),
                "scale": self.scale, "effects": self.plan.describe(), "effect_start": self.effect_start,
                "dc_bias": self.dc_bias, "stretch": np.asarray(self.stretch).tolist()}

    def save_checkpoint(self, path):
        measure.write_json(path, self.state())

    def load_checkpoint(self, path):
        try:
            with open(path) as f:
                st = json.load(f)
        except (OSError, ValueError) as e:
            raise InputError(f"{path}: cannot read checkpoint: {e}") from None
        if st.get("schema") != "drapelab-fit-checkpoint" or st.get("model") != self.kind:
            raise InputError(f"{path}: not a checkpoint of a {self.kind} fit")
        if st.get("effects", {}) != self.plan.describe():
            raise InputError(f"{path}: the checkpoint's effects {st.get('effects', {})} differ from this fit's "
                             f"{self.plan.describe()}")
        saved = np.asarray(st.get("stretch", self.stretch), dtype=float)
        if saved.shape != np.shape(self.stretch) or not np.allclose(saved, self.stretch, rtol=1e-12, atol=0.0):
            raise InputError(f"{path}: the checkpoint's fit started from another stretching table; resume it with "
                             f"the arguments it was started with (the same --init preset)")
        if set(st.get("theta", {})) != set(self.theta):
            raise InputError(f"{path}: checkpoint parameters {sorted(st.get('theta', {}))} differ from this fit's "
                             f"{sorted(self.theta)}")
        for k in self.theta:
            arr = np.asarray(st["theta"][k], dtype=float)
            if arr.shape != self.theta[k].shape or not np.all(np.isfinite(arr)):
                raise InputError(f"{path}: checkpoint parameter {k} has shape {arr.shape} or non-finite values")
            self.theta[k] = arr
            self.adam[k] = {"m": np.asarray(st["adam"][k]["m"], dtype=float), "v": np.asarray(st["adam"][k]["v"], dtype=float)}
        self.epoch = int(st["epoch"])
        self.history = list(st["history"])
        self.elapsed = float(st.get("elapsed", 0.0))
        self.start_metrics = st.get("start_metrics")
        self.lr_scale = float(st.get("lr_scale", 1.0))
        self.prior_mu = np.asarray(st.get("prior_mu", self.prior_mu), dtype=float)
        self.log_bend0 = np.asarray(st.get("log_bend0", self.log_bend0), dtype=float)
        self.scale = st.get("scale")
        self.effect_start = st.get("effect_start")
        if st.get("dc_bias") is not None:
            self.dc_bias = float(st["dc_bias"])

    # -- results
    def posterior(self):
        mean, sd = self.family.posterior(self.theta)
        bend = {"log_mean": mean.tolist(), "log_std": sd.tolist(), "median_N_m": np.exp(mean).tolist()}
        mu = self.theta["mu"]
        if mu.ndim == 3:  # a learned table per element (heter): kept in the preset
            bend["per_element_log"] = mu.reshape(mu.shape[0], -1).tolist()
        return {"bend": bend}

    def effects_block(self):
        """The preset's active_effects: fixed values, fitted means (and bdp posterior sds, 90 % intervals)."""
        if not self.plan.size:
            return self.plan.preset_block()
        std = softplus(self.theta["effect_eta"]) if self.family.stochastic else None
        return self.plan.preset_block(self.theta["effect_mu"], std)

    def preset(self, fabric=None, options=None):
        accepted = [h for h in self.history if "rejected" not in h]
        last = accepted[-1] if accepted else {}
        return {
            "schema_version": PRESET_SCHEMA_VERSION,
            "kind": "drapelab-material-preset",
            "fabric": fabric or {},
            "density_kg_m2": self.density,
            "model": self.kind,
            "parameterisation": "log bending table (3 bias angles x 5 curvature samples, N m); stretching fixed",
            "posterior": self.posterior(),
            "stretch_N_m": np.asarray(self.stretch).tolist(),
            "prior": {"log_bend_mean": self.prior_mu.tolist(), "log_bend_std": self.prior_sigma},
            "likelihood": {"sigma_obs": self.sigma_obs, "sigma_dc": self.sigma_dc, "dc_soft_bias": self.dc_bias,
                           "kl_weight": float(self.config["kl_weight"])},
            "placement_noise": {"velocity_m_s": self.placement[0], "angular_modes": self.placement[1]},
            "active_effects": self.effects_block(),
            "camera": {"kind": self.camera_kind, **self.observations[0].calibration},
            "simulation": {"mesh_level": self.mesh_level, "forward": self.config["forward"]},
            "training": {"epochs": self.epoch, "seconds": self.elapsed, "final_loss": last.get("loss"),
                         "rejected_steps": len(self.history) - len(accepted), "scale_search": self.scale,
                         "effect_start_search": self.effect_start,
                         "start": self.start_metrics, "history": self.history},
            "metrics": {"training_image": {"iou": last.get("iou"), "mse": last.get("mse")}},
            "provenance": {"images": [{"path": o.path, "sha256": o.sha256} for o in self.observations],
                           "options": options or {}, "seed": self.seed,
                           "software": f"drapelab {__import__('drapelab').__version__}",
                           "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")},
        }


def _check_fit_memory(job):
    """Refuses a fit whose lanes, images and samples would not fit in memory (budget.fit_memory_bytes)."""
    o = job.observations
    model = job.workers[0].model
    contact = any(name in ("disk_contact", "self_contact") for name in model.active_effects)
    estimate = budget.fit_memory_bytes(model.num_vertices, len(job.workers), int(job.config["dynamic"]["steps"]),
                                       len(o), o[0].mask.size, job.samples, contact=contact)
    budget.check_memory(estimate, f"this fit ({len(job.workers)} lanes on circle{job.mesh_level}, {len(o)} images of "
                        f"{o[0].mask.shape[1]} x {o[0].mask.shape[0]} px, {job.samples} samples per epoch)",
                        "use fewer --threads, fewer or smaller images")


def _plan_time_budget(job, total, t_start, calibrating, template_dir=None, guard_draws=0):
    """The split of a fit's time budget between epochs and drape calibration (see drapelab.budget), from one round
    of drapes on the calibration mesh timed now (the calibration's own lanes, forward and settings); without the
    calibration, from one drape on the fit's mesh. guard_draws > 0: fit --init's start guard evaluates two presets
    on that many draws each, on the mesh the preset ends on (the calibration's, else the fit's)."""
    config = job.config
    lanes = len(job.workers)  # the start searches' drapes run on the job's lanes
    scale_drapes = math.ceil(len(config["init"].get("scale_search") or []) / lanes)
    if job.plan.size and job.effect_start is None and job.epoch == 0:
        # the effects' start search: its candidates' drapes, start_search_drapes() each
        searched = len(job.plan.start_candidates(job.theta["effect_mu"]))
        scale_drapes += math.ceil(searched * job.start_search_drapes() / lanes)
    epoch_drapes = math.ceil(job.samples * len(job.observations) / len(job.workers))
    if not calibrating:
        model = job.workers[0].model
        bend = np.exp(job.log_bend0)
        ts = time.monotonic()
        model.simulate(model.parameters(stretch=job.stretch, bend=bend if not job.family.per_element else np.broadcast_to(
            bend, (job.num_edges,) + BEND_SHAPE)), mode="dynamic", record=False, **config["dynamic"])
        drape = time.monotonic() - ts
        guard = 2 * math.ceil(guard_draws / lanes) * drape
        return budget.FitPlan(total, time.monotonic() - t_start, 0.0, 0, 0, 0.0, drape, scale_drapes, epoch_drapes,
                              guard)
    cal = config.get("calibration") or {}
    draws = int(cal.get("draws", 8))
    lanes = max(1, min(job.threads, draws))
    level = int(cal.get("mesh_level") or job.mesh_level)
    ts = time.monotonic()
    mesh = sim.cusick_specimen(level, template_dir=template_dir)
    models = [sim.ClothModel(mesh, heterogeneous=True, density=job.density, effects=job.plan.values())
              for _ in range(lanes)]
    forward = config["evaluate"]["forward"]
    bend = np.broadcast_to(np.exp(job.log_bend0), (models[0].num_bending_edges,) + BEND_SHAPE)
    cal_obj = measure.calibration(job.observations[0].calibration["px_per_m"],
                                  tuple(job.observations[0].calibration["centre_px"]))
    shapes = _drape_draws(models, job.stretch, [bend] * lanes, forward,
                          config["dynamic"] if forward == "dynamic" else config["static"], job.placement, job.seed,
                          job.camera, cal_obj)
    round_seconds = time.monotonic() - ts
    failed = [sh["error"] for sh in shapes if "error" in sh]
    if failed:
        raise SolverError(f"time budget: the starting table does not drape on circle{level}: {failed[0]}")
    sets_min, sets_full = budget.calibration_sets(cal)
    drape_fit = round_seconds * job.workers[0].model.num_vertices / models[0].num_vertices
    share = float((config.get("time_budget") or {}).get("calibration_share", budget.DEFAULT_CALIBRATION_SHARE))
    guard = 2 * math.ceil(guard_draws / lanes) * round_seconds  # two evaluations, rounds of `lanes` drapes
    return budget.FitPlan(total, time.monotonic() - t_start, math.ceil(draws / lanes) * round_seconds, sets_min,
                          sets_full, share, drape_fit, scale_drapes, epoch_drapes, guard)


def start_options(preset, options, effects=None):
    """The FitJob options that start a fit at `preset` (a validated preset dict): its mean bending table and its
    stretching table as the start (kept as they are: no scale search, no strain-independent stretching), the
    prior's mean there when the config's prior is "start", its placement noise, its mesh level unless one is
    given, and its active effects: an effect named in `effects` is fitted (or fixed) as named there, the
    parameters it does not name keeping the preset's values (fixed); an effect it does not name stays fixed at the
    preset's values. A heter preset's per-element tables start as their mean table. The config's step sizes are
    left as they are. Returns the new options. Used by fit --init (init_options) and by diagnose's refits."""
    out = dict(options)
    config = copy.deepcopy(out.get("config") or load_config())
    config["init"] = dict(config["init"], scale_search=[], stretch_strain_dependent=True)
    if preset.get("placement_noise"):
        config["placement_noise"] = dict(preset["placement_noise"])
    out["config"] = config
    if out.get("mesh_level") is None:
        out["mesh_level"] = (preset.get("simulation") or {}).get("mesh_level")
    out["init_bend"] = np.exp(np.asarray(preset["posterior"]["bend"]["log_mean"], dtype=float))
    out["init_stretch"] = np.asarray(preset["stretch_N_m"], dtype=float)
    spec = {n: (None if v is None else dict(v)) for n, v in (effects or {}).items()}
    for name, values in fit_effects.active_effect_values(preset.get("active_effects")).items():
        if spec.get(name):  # named with some parameters: the others keep the preset's values (fixed)
            spec[name] = {**values, **spec[name]}
        elif name not in spec:
            spec[name] = dict(values)
    out["effects"] = spec
    return out


def start_guard_settings(config):
    """fit.json init_preset.start_guard as {"enabled", "draws"} (DEFAULT_START_GUARD for what it does not set);
    InputError naming the field when a value is not one."""
    given = (config.get("init_preset") or {}).get("start_guard")
    given = {} if given is None else given
    if not isinstance(given, dict):
        raise InputError(f"fit.json init_preset.start_guard: expected an object, got {given!r}")
    out = dict(DEFAULT_START_GUARD, **given)
    if not isinstance(out["enabled"], bool):
        raise InputError(f"fit.json init_preset.start_guard.enabled: true or false, got {out['enabled']!r}")
    draws = out["draws"]
    if isinstance(draws, bool) or not isinstance(draws, int) or draws < 1:
        raise InputError(f"fit.json init_preset.start_guard.draws: an integer >= 1, got {draws!r}")
    return out


START_GUARD_MIN_DRAWS = 8  # fewer draws than this (the guard's default until 2026-11-29) and the guard is skipped


def _start_guard(start, end, images, settings, seed, threads, template_dir, config, cancel_event, left, estimate,
                 progress=None):
    """fit --init's start guard: the preset the fit started from (`start`) and the one it ends with (`end`, after
    the drape calibration) evaluated on the training images with the same draws (evaluate: `draws` posterior
    draws, seed + START_GUARD_SEED_OFFSET, on the end's mesh); the start is kept when its best-of-N MSE is lower.
    The fit's objective (the expected pixel term plus the drape-coefficient term) and the best-of-N MSE a preset is
    judged by can disagree: from a diagnosis's prestrain refit, 15 epochs drifted steadily to four times the start's
    MSE (docs/lab/effect-recovery.md). With a budget (`left`: the seconds left, None: no budget; `estimate`: the
    two evaluations' estimated seconds, in rounds of `threads` draws) it runs on the draws whose rounds fit in the
    time left with budget.START_GUARD_RUN_MARGIN to spare (drape times vary between rounds; measured: a guard of
    2 x 32 draws on circle3 took 3 % more than its estimate and ended a 450 s fit 5 s late), fewer than
    `draws` when it must (recorded: draws_planned), and is skipped below min(draws, START_GUARD_MIN_DRAWS).
    Returns (the preset to write, the record for training.init.start_guard). The kept start keeps its posterior,
    effects, stretching and calibration; the training record (the epochs run) and provenance are this fit's, and
    metrics.training_image holds the guard's best-of-N IoU and MSE."""
    n = int(settings["draws"])
    record = {"draws": n, "seed": seed + START_GUARD_SEED_OFFSET, "estimate_s": estimate}
    if left is not None and estimate > 0:
        lanes = max(1, int(threads or 1))
        round_s = estimate / (2 * math.ceil(n / lanes))
        fits = int(max(left, 0.0) // (budget.START_GUARD_RUN_MARGIN * 2 * round_s)) * lanes
        if fits < min(n, START_GUARD_MIN_DRAWS):
            record["skipped"] = (f"time budget: {max(left, 0.0):.0f} s left, the start guard needs about "
                                 f"{estimate:.0f} s; the fit's end is kept")
            record["kept"] = "end"
            return end, record
        if fits < n:
            record.update(draws=fits, draws_planned=n)
            n = fits
    if progress:
        progress(dict(record, stage="start"))
    ts = time.monotonic()
    level = int(end["simulation"]["mesh_level"])
    kw = dict(samples=n, seed=seed + START_GUARD_SEED_OFFSET, threads=threads, template_dir=template_dir,
              mesh_level=level, config=config, cancel_event=cancel_event)
    for which, preset in (("start", start), ("end", end)):
        try:
            mean = evaluate(preset, images, **kw)["mean"]
        except SolverError as e:  # every draw failed to drape: that side cannot be kept
            record[f"{which}_error"] = str(e)
            continue
        record[f"{which}_mse"], record[f"{which}_iou"] = mean["mse"], mean["iou"]
    if "start_mse" not in record and "end_mse" not in record:
        raise SolverError(f"start guard: neither the start nor the fit's end drapes: {record['end_error']}")
    keep_start = "start_mse" in record and ("end_mse" not in record or record["start_mse"] < record["end_mse"])
    record.update(kept="start" if keep_start else "end", mesh_level=level, seconds=time.monotonic() - ts)
    if progress:
        progress(dict(record, stage="end"))
    if not keep_start:
        return end, record
    kept = copy.deepcopy(start)
    kept["fabric"] = end.get("fabric") or start.get("fabric") or {}
    kept["training"] = end["training"]
    kept["provenance"] = end["provenance"]
    kept["metrics"] = {"training_image": {"iou": record["start_iou"], "mse": record["start_mse"],
                                          "best_of": n}}
    return validate_preset(kept), record


def init_options(preset, options, effects=None):
    """fit --init: start_options, with every Adam step size (material, posterior sd, effects) scaled by fit.json
    init_preset.learning_rate_factor (a start near the answer); the fitted effect parameters the preset carries
    start at its values (FitJob.start_from). Returns the new options."""
    out = start_options(preset, options, effects)
    config = out["config"]
    factor = float(dict(DEFAULT_INIT_PRESET, **(config.get("init_preset") or {}))["learning_rate_factor"])
    if not math.isfinite(factor) or factor <= 0:
        raise InputError(f"fit.json init_preset.learning_rate_factor: a number > 0, got {factor}")
    config["learning_rates"] = {family: {key: factor * float(v) for key, v in rates.items()}
                                for family, rates in config["learning_rates"].items()}
    config["effects"] = dict(effect_settings(config))
    for key in ("learning_rate", "eta_learning_rate"):
        config["effects"][key] = factor * float(config["effects"][key])
    return out


def fit(images, density=None, model=None, epochs=None, time_budget=None, seed=0, out=None, checkpoint=None,
        resume=None, progress=None, cancel_event=None, fabric=None, calibration_progress=None, plan_progress=None,
        init=None, guard_progress=None, **options):
    """Fits and (when `out` is given) writes a preset. Returns the preset dict. `progress` receives each epoch's
    history entry, `calibration_progress` each drape-calibration evaluation (see calibrate_preset).

    `time_budget` (seconds) covers the whole call. A bdp fit with the drape calibration on first drapes one round
    on the calibration mesh to time it (other fits: one drape on their mesh), then splits the budget (drapelab.budget: the calibration gets what its
    fewest sets of drapes need, up to fit.json time_budget.calibration_share of the budget or what its longest
    node search needs; the epochs the rest), refusing a budget too small for the calibration, the scale search
    and one epoch with those estimates; `plan_progress` receives the split (FitPlan.as_dict). The preset records
    it in training.time_budget.

    `init` (a preset path or dict; fit --init) starts the fit where that preset left off (init_options,
    FitJob.start_from), e.g. from a diagnosis's refit DIR/presets/NAME.json with `effects` {NAME: None}: the
    material and the effect are then fitted together from there. `model` and `density` default to the preset's
    (without it: bdp, and the density must be given). The preset records it in training.init. With fit.json
    init_preset.start_guard enabled, the fit's end is then checked against its start (_start_guard: the start is
    kept when its best-of-N MSE on the training images is lower; training.init.start_guard records both;
    `guard_progress` receives the record when the guard starts and ends), unless the fit switches on an effect
    parameter the start does not carry (the start would drop it: skipped, saying so)."""
    t_start = time.monotonic()
    init_preset, init_path = None, None
    if init is not None:
        if isinstance(init, (str, os.PathLike)):
            init_path = os.fspath(init)
            init_preset = load_preset(init_path)
        elif isinstance(init, dict):
            init_preset = validate_preset(copy.deepcopy(init), "init")
        else:
            raise InputError(f"init: expected a preset path or a preset dict, got {type(init).__name__}")
        model = model or init_preset["model"]
        density = init_preset["density_kg_m2"] if density is None else density
        options = init_options(init_preset, options, options.get("effects"))
    model = model or "bdp"
    if density is None:
        raise InputError("density: give the fabric's area density in kg/m^2 (--density), or a preset to start "
                         "from (--init)")
    time_budget = budget.check_time_budget(time_budget)
    check_optional_int(seed, "seed", 0)
    check_optional_int(options.get("threads"), "threads", 1)
    if out:
        measure.check_output_path(out, "preset")
    job = FitJob(images, density, model=model, seed=seed, **options)
    init_record = None
    guard = None
    if init_preset is not None:
        init_record = {"preset": init_path, "fabric": (init_preset.get("fabric") or {}).get("name"),
                       "model": init_preset["model"], "effects_from_preset": job.start_from(init_preset)}
        guard = start_guard_settings(job.config)
        guard = guard if guard["enabled"] else None
        new = [n for n in job.plan.names if n not in init_record["effects_from_preset"]]
        if guard is not None and new:  # the start lacks what the user switched on: not a start to go back to
            init_record["start_guard"] = {"skipped": f"the fit switches on {', '.join(new)}, which the start does "
                                                     f"not carry; the fit's end is kept", "kept": "end"}
            guard = None
    if resume:
        job.load_checkpoint(resume)
    calibrating = job.family.stochastic and (job.config.get("calibration") or {}).get("enabled", False)
    plan = None
    epoch_budget = time_budget
    if time_budget is not None:
        plan = _plan_time_budget(job, time_budget, t_start, calibrating, options.get("template_dir"),
                                 guard["draws"] if guard else 0).check()
        if plan_progress:
            plan_progress(plan.as_dict())
        epoch_budget = plan.epochs - (time.monotonic() - t_start - plan.setup)
    epochs_before = job.epoch
    job.run(epochs=epochs, time_budget=epoch_budget, progress=progress, cancel_event=cancel_event,
            checkpoint=checkpoint)
    if job.epoch == 0 and time_budget is not None:
        raise InputError(f"time_budget: {time_budget:g} s ran out before the first epoch ("
                         f"{time.monotonic() - t_start:.1f} s spent on set-up and the scale search)")
    preset = job.preset(fabric=fabric, options={"model": model, "epochs": epochs, "time_budget": time_budget,
                                                "seed": seed, "effects": job.plan.describe(),
                                                **{k: v for k, v in options.items()
                                                   if k not in ("config", "effects", "calibration", "init_bend",
                                                                "init_stretch")}})
    epochs_end = time.monotonic() - t_start
    if calibrating:
        left = None if time_budget is None else time_budget - epochs_end - (plan.start_guard if guard else 0.0)
        preset = calibrate_preset(preset, images, seed=seed, threads=job.threads, template_dir=options.get("template_dir"),
                                  config=job.config, cancel_event=cancel_event, progress=calibration_progress,
                                  time_budget=left)
    if guard is not None:
        left = None if time_budget is None else time_budget - (time.monotonic() - t_start)
        estimate = plan.start_guard_estimate if plan is not None else 0.0
        preset, init_record["start_guard"] = _start_guard(
            init_preset, preset, images, guard, seed, job.threads, options.get("template_dir"), job.config,
            cancel_event, left, estimate, guard_progress)
    if init_record is not None:  # set on the preset written: the drape calibration returns a copy
        preset["training"]["init"] = init_record
    if time_budget is not None:
        preset["training"]["time_budget"] = dict(plan.as_dict(),
                                                 epochs_run=job.epoch - epochs_before, epochs_end_s=epochs_end,
                                                 end_s=time.monotonic() - t_start)
    if out:
        write_preset(out, preset)
    return preset


def write_preset(path, preset):
    measure.write_json(path, validate_preset(preset, path))


def _float_array(value, source, what):
    """A JSON table as a float array; InputError naming `what` when it is not a table of numbers."""
    def numbers_only(v):
        if isinstance(v, (list, tuple)):
            return all(numbers_only(x) for x in v)
        if isinstance(v, np.ndarray):
            return v.dtype.kind in "iuf"
        return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))

    if not numbers_only(value):  # a string "0" or a true in a table is a mistake, not a number to coerce
        raise InputError(f"{source}: {what} must be a table of numbers")
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"{source}: {what} must be a table of numbers") from None


def _json_number(value):
    """A JSON number (not a bool) as a float (inf beyond the float range), else None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        return float(value)
    except OverflowError:
        return math.inf


def migrate_preset(preset, source="preset"):
    """A preset of an older schema version brought to the current one (a new dict; the current version is
    returned as is). Newer versions are refused: their fields may mean what this drapelab cannot know.
    1 -> 2: active_effects (always empty in version 1) holds the effects' values; nothing else changed."""
    if not isinstance(preset, dict) or preset.get("kind") != "drapelab-material-preset":
        raise InputError(f"{source}: not a drapelab material preset")
    version = preset.get("schema_version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise InputError(f"{source}: schema_version must be a positive integer, got {version!r}")
    if version > PRESET_SCHEMA_VERSION:
        raise InputError(f"{source}: written by a newer drapelab (preset schema version {version}; this drapelab "
                         f"reads versions 1 to {PRESET_SCHEMA_VERSION}): update drapelab to load it")
    if version == 1:
        if preset.get("active_effects") not in (None, {}):
            raise InputError(f"{source}: a version 1 preset cannot carry active_effects (got "
                             f"{preset.get('active_effects')!r})")
        preset = dict(preset, schema_version=2, active_effects={})
    return preset


def validate_preset(preset, source="preset"):
    """Checks a preset (migrating an older schema version first) and returns it (the migrated copy)."""
    preset = migrate_preset(preset, source)
    if preset.get("model") not in MODELS:
        raise InputError(f"{source}: unknown model {preset.get('model')!r}")
    try:
        check_density(preset.get("density_kg_m2"))
    except InputError as e:
        raise InputError(f"{source}: {str(e).replace('density:', 'density_kg_m2:', 1)}") from None
    posterior = preset.get("posterior", {})
    bend = posterior.get("bend", {}) if isinstance(posterior, dict) else None
    if not isinstance(bend, dict):
        raise InputError(f"{source}: posterior bend must be an object holding log_mean and log_std tables")
    for key in ("log_mean", "log_std"):
        arr = _float_array(bend.get(key, []), source, f"posterior bend {key}")
        if arr.shape != BEND_SHAPE:
            raise InputError(f"{source}: posterior bend {key} must be a 3 x 5 table, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise InputError(f"{source}: posterior bend {key} contains NaN or infinity")
        if key == "log_std" and np.any(arr < 0):
            raise InputError(f"{source}: posterior bend log_std must be >= 0")
    g = _json_number(bend.get("global_log_std", 0.0))
    if g is None or not 0 <= g <= 5:
        raise InputError(f"{source}: posterior bend global_log_std must be a number in [0, 5], "
                         f"got {bend.get('global_log_std')!r}")
    stretch = _float_array(preset.get("stretch_N_m", []), source, "stretch_N_m")
    if stretch.shape != tables.STRETCH_SHAPE or not np.all(np.isfinite(stretch)):
        raise InputError(f"{source}: stretch_N_m must be a finite 6 x 4 table")
    negative = np.argwhere(np.delete(stretch, 1, axis=1) < 0)  # c12 (column 1), a Poisson coupling, may be < 0
    if negative.size:
        row, col = int(negative[0][0]), int(negative[0][1])
        col += col >= 1
        raise InputError(f"{source}: stretch_N_m must be >= 0 (except c12), got {stretch[row, col]:g} at row {row} "
                         f"{tables.STRETCH_COLUMNS[col]}")
    placement = preset.get("placement_noise")
    if placement is not None:
        if not isinstance(placement, dict):
            raise InputError(f"{source}: placement_noise must be an object (velocity_m_s, angular_modes)")
        a, k = placement.get("velocity_m_s"), placement.get("angular_modes")
        speed = _json_number(a)
        if speed is None or not 0 <= speed <= 1.0:
            raise InputError(f"{source}: placement_noise velocity_m_s must be a number in [0, 1] m/s, got {a!r}")
        if isinstance(k, bool) or not isinstance(k, int) or not 0 <= k <= 64:
            raise InputError(f"{source}: placement_noise angular_modes must be an integer in [0, 64], got {k!r}")
    if "per_element_log" in bend:
        pe = _float_array(bend["per_element_log"], source, "posterior bend per_element_log")
        if pe.ndim != 2 or pe.shape[1] != 15 or not np.all(np.isfinite(pe)):
            raise InputError(f"{source}: posterior bend per_element_log must be finite (E, 15)")
    fit_effects.validate_active_effects(preset.get("active_effects", {}), source)
    return preset


def load_preset(path):
    try:
        with open(path) as f:
            preset = json.load(f)
    except OSError as e:
        raise InputError(f"{path}: cannot read preset: {e.strerror}") from None
    except ValueError as e:
        raise InputError(f"{path}: not valid JSON: {e}") from None
    except RecursionError:
        raise InputError(f"{path}: not valid JSON: nested too deeply") from None
    return validate_preset(preset, path)


def preset_bend_samples(preset, num_edges, rng, count):
    """`count` per-element bending tables (count, E, 3, 5) drawn from a preset's posterior.

    A bdp posterior with `global_log_std` g > 0 (set by the drape calibration, see calibrate_preset) also
    scales each draw as a whole: log B_w = mu + g z + sd * eps_w, z ~ N(0, 1) per draw (drawn after eps)."""
    bend = preset["posterior"]["bend"]
    mu = np.asarray(bend["log_mean"])
    sd = np.asarray(bend["log_std"])
    if preset["model"] == "heter" and "per_element_log" in bend:
        pe = np.asarray(bend["per_element_log"]).reshape(-1, *BEND_SHAPE)
        if pe.shape[0] == num_edges:
            return np.exp(np.broadcast_to(pe, (count,) + pe.shape))
        mu = pe.mean(axis=0)  # different mesh: fall back to the element mean
        sd = np.zeros(BEND_SHAPE)
    noise = rng.standard_normal((count, num_edges) + BEND_SHAPE)
    log_b = mu[None, None] + sd[None, None] * noise
    g = float(bend.get("global_log_std", 0.0) or 0.0)
    if g > 0:
        log_b += g * rng.standard_normal(count)[:, None, None, None]
    return np.exp(log_b)


def _stretch_search(nodes0, nodes_at, observed, lo, hi, tolerance, patience):
    """The node search's steps (calibrate_preset step 3): from nodes0 (the predictive mean node count at stretching
    2^0) step s = +-1, +-2, ... towards `observed` within [lo, hi], nodes_at(s) giving the count at 2^s (None: that
    stretching does not drape, the search ends). Ends within `tolerance`, on crossing, or after `patience` steps in
    a row that come less than 0.1 closer than the closest so far. Returns the visited s in order (not 0)."""
    visited, gap0 = [], nodes0 - observed
    if abs(gap0) <= tolerance:
        return visited
    d = 1 if gap0 < 0 else -1
    s, closest, stale = 0, abs(gap0), 0
    while lo <= s + d <= hi:
        nodes = nodes_at(s + d)
        if nodes is None:
            break
        s += d
        visited.append(s)
        signed = nodes - observed
        if abs(signed) <= tolerance or (signed > 0) != (gap0 > 0):
            break
        stale = stale + 1 if abs(signed) > closest - 0.1 else 0
        closest = min(closest, abs(signed))
        if stale >= patience:
            break
    return visited


def _bracket_midpoint(signed, tolerance):
    """The node search's refinement (node_search.refine): `signed` maps each stretching evaluated (log2 scale v) to
    its predictive mean node count minus the observed. Where two neighbours one octave apart bracket the observed
    count (opposite signs) and neither is within `tolerance`, returns the half-octave between them (of several such
    pairs, the one with the smaller gaps); else None."""
    pairs = [(abs(signed[a]) + abs(signed[a + 1]), a + 0.5) for a in signed
             if a + 1 in signed and signed[a] * signed[a + 1] < 0
             and abs(signed[a]) > tolerance and abs(signed[a + 1]) > tolerance]
    return min(pairs)[1] if pairs else None


def calibrate_preset(preset, images, seed=0, threads=None, template_dir=None, config=None, cancel_event=None,
                     progress=None, time_budget=None):
    """The drape calibration of a bdp posterior (the last stage of `fit`; also applies to an existing preset).

    1. Scale: the fitted mean table is shifted by one global log factor c so that the posterior-predictive
       mean drape coefficient of `draws` draws (fit.json calibration.draws; common random numbers: the same
       element noise and placements at every c) equals the training images' mean drape coefficient. The
       pixel term of the fit leaves it 0.01-0.05 off (measured on fabrics 1-5); the drape coefficient is the
       rotation-free summary a textile lab reads first. Secant steps on c from the slope
       s = dDC/dc measured by central differences (step calibration.log_step); no step shorter than
       calibration.shift_tolerance.
    2. Spread: the posterior over the fabric's overall stiffness that one (or n) drape(s) leave. A fabric's
       drapes scatter (new specimens and re-drapes alike): by sd_f in drape coefficient, i.e. by
       L = sd_f / s in log bending scale, about the same for every fabric (fit.json calibration.drape_log_sd,
       pooled over fabrics 11-20 of the dataset, tools/drape_variability.py; in drape-coefficient units it
       differs by 5x between fabrics, in log scale much less). The fabric's mean scale is then known to
       L / sqrt(n), and a new drape varies by L around it: predictive variance L^2 (1 + 1/n). The simulated
       draws already vary (element noise, placement) by s_sim in drape coefficient; the remainder goes into
       a per-draw global log factor of sd g = sqrt(max(0, L^2 (1 + 1/n) - (s_sim / s)^2)), stored as
       posterior.bend.global_log_std (see preset_bend_samples). L is measured at the fit's stretching; where
       step 3 changes the stretching (and the slope s to s'), the drape-coefficient spread (L s)^2 (1 + 1/n)
       is kept: g = sqrt(max(0, (L s)^2 (1 + 1/n) - s_sim^2)) / s'. Both slopes are central differences
       (+-log_step) at the calibrated shift.
    3. Node count (calibration.node_search): at a given drape coefficient, stiffer in-plane stretching gives more
       folds (fabric 5 on circle3 at DC 0.8: stretching x0.1 2-3 nodes, x1 5-6, x10 6-8; observed 6-9). One
       silhouette's node count thus pins the stretching the pixel fit leaves free: the stretching table is scaled
       by 2^s, s = +-1, +-2, ... towards the training images' mean node count, the bending shift re-calibrated
       (secant steps, from the last shift) at each, until the predictive mean node count is within tolerance,
       crosses it or has not come 0.1 closer for `patience` steps in a row; with node_search.refine, where two
       neighbouring octaves bracket the observed count and neither is within tolerance, the half-octave between
       them is tried too; the closest s is kept (within a quarter node of it, the smallest |s|), and step 2 uses
       its drapes and slope.
    The drapes run on calibration.mesh_level (default 3: circle2 folds fewer nodes than the finer meshes), which
    becomes the preset's simulation.mesh_level (the fit's is kept as calibration.fit_mesh_level).
    `progress` (optional) is called after every new set of drapes with {"stage": "calibration", "evaluation" (1, 2,
    ...), "stretch_scale", "bend_scale" (exp of the log shift), "dc", "dc_sd", "nodes", "dc_observed",
    "nodes_observed", "seconds" (since the calibration began)}: one per entry of the record's "evaluated".
    Returns a new preset with the shifted log_mean, global_log_std, the scaled stretching and a "calibration"
    record (what was measured, every set of drapes in "evaluated", and the fit.json settings used in "settings").
    A preset that was calibrated before is first taken back to its fit (shift, stretching scale and mesh level
    undone): calibrating is idempotent.
    `time_budget` (seconds, optional): the first three sets of drapes (the mean drape coefficient and the slope at
    the fit's scale) always run; every later set only if it and the sets that must follow it fit in what is left,
    at the longest set measured so far: a node-search step (and the refinement) needs its two sets and the secant
    steps and slope after it, a secant step itself and a slope; a central slope that does not fit is replaced by
    the one at the fit's scale (record: "time_budget_s", "node_search_stopped_by_time_budget",
    "skipped_by_time_budget"; every evaluated entry has its "seconds")."""
    preset = validate_preset(json.loads(json.dumps(preset)))
    if preset["model"] != "bdp":
        raise InputError(f"calibrate: only a bdp posterior is calibrated (this preset is {preset['model']!r})")
    previous = preset.pop("calibration", None)
    if previous is not None:  # back to the fit: its table, stretching and mesh
        mu = np.asarray(preset["posterior"]["bend"]["log_mean"]) - float(previous["log_scale_shift"])
        preset["posterior"]["bend"].update({"log_mean": mu.tolist(), "median_N_m": np.exp(mu).tolist(),
                                            "global_log_std": 0.0})
        preset["stretch_N_m"] = (np.asarray(preset["stretch_N_m"]) / float(previous.get("stretch_scale", 1.0))).tolist()
        preset["simulation"]["mesh_level"] = int(previous.get("fit_mesh_level", preset["simulation"]["mesh_level"]))
    config = config or load_config()
    opts = config.get("calibration") or {}
    k = int(opts.get("draws", 8))
    step = float(opts.get("log_step", 0.2))
    spread = float(opts.get("drape_log_sd", 0.0))
    if k < 2 or not step > 0 or not spread >= 0:
        raise InputError("fit.json calibration: need draws >= 2, log_step > 0, drape_log_sd >= 0")
    search = opts.get("node_search") or {}
    lo_s, hi_s = int(search.get("min_log2", 0)), int(search.get("max_log2", 0))
    tolerance = float(search.get("tolerance", 0.5))
    patience = int(search.get("patience", 2))
    refine = bool(search.get("refine", False))
    if not (lo_s <= 0 <= hi_s) or not tolerance > 0 or patience < 1:
        raise InputError("fit.json calibration.node_search: need min_log2 <= 0 <= max_log2, tolerance > 0 and "
                         "patience >= 1")
    search_settings = {"enabled": bool(search.get("enabled", False)), "min_log2": lo_s, "max_log2": hi_s,
                       "tolerance": tolerance, "patience": patience, "refine": refine}
    if not search.get("enabled", False):
        lo_s = hi_s = 0
    iterations = int(opts.get("iterations", 2))
    shift_tolerance = float(opts.get("shift_tolerance", 0.0))
    if not shift_tolerance >= 0:
        raise InputError("fit.json calibration: need shift_tolerance >= 0")
    if not images:
        raise InputError("images: give the training silhouettes")
    time_budget = None if time_budget is None else float(time_budget)  # may be <= 0: steps 1-2 run regardless
    t0 = time.monotonic()
    fit_level = int(preset["simulation"]["mesh_level"])
    level = int(opts.get("mesh_level") or fit_level)
    if level not in (1, 2, 3, 4, 5):
        raise InputError(f"fit.json calibration.mesh_level: expected 1..5 (circle1..circle5), got {level}")
    preset["simulation"]["mesh_level"] = level
    observations = [_Observation(p, None) for p in images]
    observed = float(np.mean([o.dc for o in observations]))
    observed_nodes = float(np.mean([o.nodes for o in observations]))
    lanes = max(1, min(default_threads(config, threads), k))
    predictive = _Predictive(preset, observations[0].mask.shape, lanes, config, template_dir)
    stretch0 = np.asarray(preset["stretch_N_m"], dtype=float)
    bend = preset["posterior"]["bend"]
    base = dict(preset, posterior={"bend": dict(bend, global_log_std=0.0)})
    draws = preset_bend_samples(base, predictive.num_edges, np.random.default_rng([seed, 7]), k)
    evaluated = {}  # (log2 stretch scale, log bending shift) -> (mean DC, sd DC, mean node count)

    set_seconds = {}  # (log2 stretch scale, log bending shift) -> seconds of that set of drapes
    stopped = []  # node-search steps not taken for lack of time
    skipped = []  # other sets of drapes not made for lack of time (what was used instead)

    def affordable(sets):
        """Whether `sets` more sets of drapes fit in the time budget (at the longest set so far)."""
        if time_budget is None:
            return True
        return time.monotonic() - t0 + sets * max(set_seconds.values()) <= time_budget

    # Sets of drapes that follow the node search when it moved the stretching: the bending secant steps there and
    # the slope's central difference.
    tail = iterations + 2

    def measure_at(s, c):
        if (s, c) not in evaluated:
            ts = time.monotonic()
            predictive.stretch = stretch0 * 2.0 ** s
            shapes = [sh for sh in predictive.drape(draws * math.exp(c), seed, cancel_event=cancel_event)
                      if "error" not in sh]
            if len(shapes) < 2:
                raise SolverError(f"calibrate: the drapes of {k - len(shapes)} of {k} draws failed at log scale "
                                  f"{c:+.3f}, stretching x{2.0 ** s:g}")
            dcs = [sh["dc"] for sh in shapes]
            evaluated[(s, c)] = (float(np.mean(dcs)), float(np.std(dcs, ddof=1)),
                                 float(np.mean([sh["nodes"] for sh in shapes])))
            set_seconds[(s, c)] = time.monotonic() - ts
            if progress:
                dc_, sd_, nodes_ = evaluated[(s, c)]
                progress({"stage": "calibration", "evaluation": len(evaluated), "stretch_scale": 2.0 ** s,
                          "bend_scale": math.exp(c), "dc": dc_, "dc_sd": sd_, "nodes": nodes_, "dc_observed": observed,
                          "nodes_observed": observed_nodes, "seconds": time.monotonic() - t0})
        return evaluated[(s, c)]

    def fit_scale(s, c, slope, iterations):
        """Secant steps on the bending log shift c (from c) until the mean DC meets the observed one."""
        dc, local = measure_at(s, c)[0], slope
        for _ in range(iterations):
            c_new = float(np.clip(c + (observed - dc) / local, c - 1.0, c + 1.0))
            if abs(c_new - c) < max(shift_tolerance, 1e-4):  # a step that would not move the drape coefficient
                break
            if not affordable(1 + 2):  # the step and a central slope after it
                skipped.append(f"secant step at stretching x{2.0 ** s:g}")
                break
            dc_new = measure_at(s, c_new)[0]
            if abs(dc_new - dc) > 1e-6 and (dc_new - dc) / (c_new - c) > 1e-3:
                local = (dc_new - dc) / (c_new - c)
            c, dc = c_new, dc_new
        best = min((key for key in evaluated if key[0] == s), key=lambda key: abs(evaluated[key][0] - observed))
        return best[1], local  # the best evaluated shift at this stretching

    before = measure_at(0, 0.0)
    slope = (measure_at(0, step)[0] - measure_at(0, -step)[0]) / (2 * step)
    if not slope > 1e-3:
        raise SolverError(f"calibrate: the drape coefficient does not grow with the bending scale here "
                          f"(slope {slope:.4g} per log unit): cannot calibrate")
    chosen = {0: (fit_scale(0, 0.0, slope, iterations)[0], slope)}  # stretching 2^s -> (shift, slope dDC/dc)
    # 3. Node count: at a given drape coefficient, stiffer in-plane stretching gives more (and finer) folds (the
    # hoop shortening of the hanging annulus goes into folds rather than in-plane compression). The stretching
    # table is scaled by powers of 2 towards the training images' node count, the bending shift re-calibrated
    # to the drape coefficient at each, until the predictive mean node count meets or crosses the observed.
    # `patience` steps in a row that do not bring the node count at least 0.1 closer than the closest so far end
    # the search (the node count of some fabrics hardly depends on the stretching: fabric 1 stays at 7.1-7.4 from
    # x1 to x16; others sit on a plateau for one step: fabric 5 5.6 at x1 and x2, then rises); each step takes one
    # secant step on the bending from the last shift.
    def nodes_at(v):
        """Stretching 2^v, one secant step on the bending from the neighbour's shift; None: it does not drape."""
        prev = v - 1 if v > 0 else v + 1
        if not affordable(2 + tail + (2 if refine else 0)):
            stopped.append(v)
            return None
        try:
            chosen[v] = fit_scale(v, chosen[prev][0], chosen[prev][1], 1)
        except SolverError:
            return None
        return evaluated[(v, chosen[v][0])][2]

    def gap(v):
        return abs(evaluated[(v, chosen[v][0])][2] - observed_nodes)

    _stretch_search(evaluated[(0, chosen[0][0])][2], nodes_at, observed_nodes, lo_s, hi_s, tolerance, patience)
    # An octave can be too coarse a step: fabric 5 measured 6.5 nodes at x8 and 7.75 at x16 for 7 observed.
    # Where the search bracketed the observed count between two neighbours, neither within tolerance, one
    # half-octave between them (one secant step on the bending from the neighbour closer in nodes).
    mid = _bracket_midpoint({v: evaluated[(v, chosen[v][0])][2] - observed_nodes for v in chosen}, tolerance) \
        if refine else None
    if mid is not None and not affordable(2 + tail):
        stopped.append(mid)
        mid = None
    if mid is not None:
        near = min((mid - 0.5, mid + 0.5), key=gap)
        try:
            chosen[mid] = fit_scale(mid, chosen[near][0], chosen[near][1], 1)
        except SolverError:
            pass
    # The closest; within a quarter node of it (sampling noise of 8 draws), the smallest change of stretching.
    best = min(gap(v) for v in chosen)
    s = min((v for v in chosen if gap(v) <= best + 0.25), key=abs)
    c = chosen[s][0]
    if s != 0:  # the search took one secant step per stretching: finish the bending scale at the chosen one
        c = fit_scale(s, c, chosen[s][1], iterations)[0]
    dc, s_sim, nodes = evaluated[(s, c)]
    n = len(observations)

    def central_slope(v, at):
        """dDC/dlog(bending scale) by central differences of +-log_step (the secant slopes of the root finding
        come from steps down to 0.007 and fold jumps make them 4x off: fabric 2 at x8, 0.80 against 0.18). A
        central difference already made about a centre within log_step / 4 of `at` is reused (the same 0.4-wide
        difference, moved by a tenth of its width; two sets of drapes fewer)."""
        centres = [a for (w, a) in evaluated if w == v and abs(a - at) <= step / 4 + 1e-12
                   and (v, a + step) in evaluated and (v, a - step) in evaluated]
        if centres:
            at = min(centres, key=lambda a: abs(a - at))
        elif not affordable(2):  # out of time: the central difference at the fit's scale and stretching
            skipped.append(f"slope at stretching x{2.0 ** v:g}, shift {at:+.3f} (the slope at the fit's scale used)")
            return slope
        return (measure_at(v, at + step)[0] - measure_at(v, at - step)[0]) / (2 * step)

    # The drape scatter L is a log-bending sd at the fit's stretching (where drape_log_sd was measured): in drape
    # coefficient it is L * slope there; at another stretching the slope may differ, so the predictive keeps that
    # drape-coefficient spread, not L in log units.
    slope_fit = central_slope(0, chosen[0][0])
    slope_used = slope_fit if s == 0 else central_slope(s, c)
    if not (slope_fit > 1e-3 and slope_used > 1e-3):
        raise SolverError(f"calibrate: the drape coefficient does not grow with the bending scale at the "
                          f"calibrated scale (slopes {slope_fit:.4g}, {slope_used:.4g} per log unit)")
    target = (spread * slope_fit) ** 2 * (1 + 1 / n)  # predictive DC variance
    g = math.sqrt(max(0.0, target - s_sim ** 2)) / slope_used
    mu = np.asarray(bend["log_mean"]) + c
    preset["posterior"]["bend"].update({"log_mean": mu.tolist(), "median_N_m": np.exp(mu).tolist(),
                                        "global_log_std": g})
    preset["stretch_N_m"] = (stretch0 * 2.0 ** s).tolist()
    preset["calibration"] = {
        "dc_observed": observed, "dc_predicted_before": before[0], "dc_predicted": dc, "log_scale_shift": c,
        "slope_dc_per_log": slope_used, "slope_dc_per_log_fit": slope_fit, "dc_sd_simulated": s_sim,
        "drape_log_sd": spread, "global_log_std": g,
        "nodes_observed": observed_nodes, "nodes_predicted_before": before[2], "nodes_predicted": nodes,
        "stretch_scale": 2.0 ** s, "mesh_level": level, "fit_mesh_level": fit_level,
        "draws": k, "settings": {"draws": k, "iterations": iterations, "log_step": step,
                                 "shift_tolerance": shift_tolerance, "node_search": search_settings},
        "evaluated": [{"stretch_scale": 2.0 ** key[0], "log_scale_shift": key[1], "dc": v[0],
                                   "dc_sd": v[1], "nodes": v[2], "seconds": set_seconds[key]}
                      for key, v in sorted(evaluated.items())],
        "time_budget_s": time_budget, "node_search_stopped_by_time_budget": bool(stopped),
        "skipped_by_time_budget": skipped,
        "seconds": time.monotonic() - t0}
    return validate_preset(preset)


def _hard_image(camera, x, faces):
    return np.asarray(render.hard_silhouette(camera, x, faces), dtype=np.float64)


class _Predictive:
    """What posterior-predictive drapes of a preset need, shared by evaluate and calibrate_preset (so that the
    calibration sees the drapes evaluation will): the preset's camera on images of `shape`, one model per lane
    on its mesh level (or `mesh_level`), its stretching table and placement noise (bdp presets without one:
    fit.json's), the forward of `forward` (default fit.json evaluate.forward)."""

    def __init__(self, preset, shape, lanes, config, template_dir=None, mesh_level=None, forward=None):
        cal = preset["camera"]
        self.camera = _camera_for(cal.get("kind", "ortho"), {"px_per_m": cal["px_per_m"], "centre_px": cal["centre_px"]},
                                  shape)
        self.calibration = measure.calibration(cal["px_per_m"], tuple(cal["centre_px"]))
        self.level = mesh_level or preset["simulation"]["mesh_level"]
        mesh = sim.cusick_specimen(self.level, template_dir=template_dir)
        self.effects = preset.get("active_effects") or {}
        self.models = [sim.ClothModel(mesh, heterogeneous=True, density=preset["density_kg_m2"],
                                      effects=fit_effects.active_effect_values(self.effects), px_per_m=cal["px_per_m"])
                       for _ in range(lanes)]
        self.num_edges = self.models[0].num_bending_edges
        self.stretch = np.asarray(preset["stretch_N_m"])
        self.forward = forward or config["evaluate"]["forward"]
        self.mode_opts = config["dynamic"] if self.forward == "dynamic" else config["static"]
        placement = preset.get("placement_noise") or (config.get("placement_noise") if preset["model"] == "bdp" else None) or {}
        self.placement = (float(placement.get("velocity_m_s", 0.0)), int(placement.get("angular_modes", 0)))
        self.loop = None  # the native loop of its drapes (built at the first)

    def drape(self, draws, seed, progress=None, cancel_event=None):
        """Drapes bending draws; the effects of draw i are drawn from the preset's active_effects with
        default_rng([seed, 11]) (fixed and point-estimate effects: their values)."""
        effects = fit_effects.sample_effect_values(self.effects, np.random.default_rng([seed, 11]), len(draws))
        if self.loop is None:
            self.loop = _predictive_loop(self.models, self.camera, self.forward, self.mode_opts)
        return _drape_draws(self.models, self.stretch, draws, self.forward, self.mode_opts, self.placement, seed,
                            self.camera, self.calibration, progress, cancel_event, effects, self.loop)


def _drape_draws(models, stretch, draws, fwd, mode_opts, placement, seed, camera, cal_obj, progress=None,
                 cancel_event=None, effects=None, loop=None):
    """Drapes draws[i] (one lane per model, in the native sample loop `loop`, built here when not given) from the
    flat state, draw i with the placement velocities of default_rng([seed, i, 1]) and the effect values effects[i]
    (None: the models' own). Returns per draw {"x", "image", "dc", "nodes"} or {"error"}."""
    amplitude, modes = placement
    rest = models[0].rest_positions
    m = models[0]
    batch = []
    for i in range(len(draws)):
        p = m.parameters(stretch=stretch, bend=draws[i], effects=effects[i] if effects else None)
        v0 = placement_velocities(rest, np.random.default_rng([seed, i, 1]), amplitude, modes) if amplitude > 0 else None
        batch.append(native.infer.SampleDraw(p, None if v0 is None else v0.ravel()))
    if loop is None:
        loop = _predictive_loop(models, camera, fwd, mode_opts)
    seen = [0]

    def reported(done, total):  # the loop polls at every solver step; report each finished draw once
        if progress and done > seen[0]:
            seen[0] = done
            progress(done, total)

    out = loop.predict(batch, sim._progress_sink(reported if progress else None, cancel_event, "predictive drapes"))
    shapes = []
    for x, img, error in out:
        if error is not None:  # a draw whose drape fails is reported, not fatal
            shapes.append({"error": error})
            continue
        img = np.asarray(img)
        nodes = measure.analyse_nodes(measure.r_theta(img, cal_obj))
        shapes.append({"x": np.asarray(x).reshape(-1, 3), "image": img,
                       "dc": measure.drape_coefficient(img, cal_obj.px_per_m), "nodes": nodes.count,
                       "amplitude": nodes.amplitude_m})
    return shapes


def _predictive_loop(models, camera, fwd, mode_opts):
    """The native loop of predictive drapes on `models`: fwd "dynamic" (mode_opts: rollout settings) or "static"
    (mode_opts: Newton settings)."""
    static = fwd == "static"
    return _native_loop(models, camera, static, {} if static else mode_opts, mode_opts if static else {})


def _best_of_curve(mses):
    """{"1": .., "10": .., "100": .., ..., "N": ..}: the best MSE among the first k draws (the draws are independent,
    so a prefix is a best-of-k), k = 1, 10, 100, ... below N, and N: how far more draws would go."""
    ks = [10 ** e for e in range(int(math.log10(len(mses))) + 1) if 10 ** e < len(mses)] + [len(mses)]
    running = np.minimum.accumulate(np.asarray(mses, dtype=float))
    return {str(k): float(running[k - 1]) for k in ks}


def evaluate(preset_or_path, images, meshes=None, samples=None, seed=0, threads=None, template_dir=None,
             mesh_level=None, forward=None, progress=None, cancel_event=None, config=None):
    """Posterior-predictive evaluation of a preset on test silhouettes (and, optionally, their 3D meshes).

    Draws `samples` parameter sets (default fit.json: 1000 for bdp, 1 for homo/heter), drapes each once from
    the flat rest state (the paper's protocol: the same draws serve every test image) and reports, per image:
    best-of-N pixel `mse` and `iou` (hard silhouettes), `mse_best_of` (best of the first 1, 10, 100, ... draws
    and of all N), `hausdorff_m` of the best sample's mesh to the given mesh, the drape coefficient (observed,
    posterior-predictive mean, 90 % interval), the node count (observed, predictive mode) and the node amplitude
    (half the mean peak-to-trough depth of the folds; observed, predictive mean, 90 % interval: how deep the model's
    folds are against the measured ones). `mean` averages them and gives coverage fractions and the signed
    amplitude bias (predicted mean - observed; < 0: the model's folds are shallower than the measured ones).
    """
    preset = load_preset(preset_or_path) if isinstance(preset_or_path, (str, os.PathLike)) else validate_preset(preset_or_path)
    config = config or load_config()
    if not images:
        raise InputError("images: give at least one test silhouette")
    meshes = list(meshes or [])
    if meshes and len(meshes) != len(images):
        raise InputError(f"meshes: {len(meshes)} meshes for {len(images)} images (they pair in order)")
    kind = preset["model"]
    check_optional_int(seed, "seed", 0)
    check_optional_int(threads, "threads", 1)
    n = int(samples) if samples is not None else int(config["evaluate"]["samples"][kind])
    if n < 1:
        raise InputError(f"samples: must be >= 1, got {samples}")
    observations = [_Observation(p, None) for p in images]
    lanes = max(1, min(default_threads(config, threads), n))
    predictive = _Predictive(preset, observations[0].mask.shape, lanes, config, template_dir, mesh_level, forward)
    shape = observations[0].mask.shape
    budget.check_memory(budget.evaluate_memory_bytes(predictive.models[0].num_vertices, predictive.num_edges, lanes, n, len(observations),
                                                     observations[0].mask.size),
                        f"evaluate ({n} draws on circle{predictive.level}, {len(observations)} images of "
                        f"{shape[1]} x {shape[0]} px)", "use fewer --samples or smaller images")
    draws = preset_bend_samples(preset, predictive.num_edges, np.random.default_rng(seed), n)
    shapes = predictive.drape(draws, seed, progress, cancel_event)
    failed = [s["error"] for s in shapes if "error" in s]
    shapes = [s for s in shapes if "error" not in s]
    if not shapes:
        raise SolverError(f"evaluate: every one of the {n} posterior draws failed to drape; first: {failed[0]}")
    dcs = np.array([s["dc"] for s in shapes])
    nodes = np.array([s["nodes"] for s in shapes])
    values, counts = np.unique(nodes, return_counts=True)
    node_mode = int(values[np.argmax(counts)])
    lo, hi = (float(v) for v in np.percentile(dcs, [5, 95]))
    amps = np.array([s["amplitude"] for s in shapes])
    amp_lo, amp_hi = (float(v) for v in np.percentile(amps, [5, 95]))
    per_image = []
    for k, o in enumerate(observations):
        mses = np.array([measure.pixel_mse(s["image"], o.mask) for s in shapes])
        best = int(np.argmin(mses))
        entry = {"image": images[k], "mse": float(mses[best]), "iou": float(measure.iou(shapes[best]["image"], o.mask)),
                 "best_sample": best, "mse_best_of": _best_of_curve(mses),
                 "drape_coefficient": {"observed": o.dc, "predicted_mean": float(dcs.mean()),
                                       "interval90": [lo, hi]},
                 "node_count": {"observed": o.nodes, "predicted_mode": node_mode},
                 "node_amplitude_m": {"observed": o.amplitude, "predicted_mean": float(amps.mean()),
                                      "interval90": [amp_lo, amp_hi]}}
        if meshes:
            entry["hausdorff_m"] = float(measure.hausdorff_distance((shapes[best]["x"], predictive.models[0].faces), meshes[k]))
        per_image.append(entry)
    mean = {"mse": float(np.mean([e["mse"] for e in per_image])),
            "iou": float(np.mean([e["iou"] for e in per_image])),
            "dc_abs_error": float(np.mean([abs(e["drape_coefficient"]["predicted_mean"] - e["drape_coefficient"]["observed"])
                                           for e in per_image])),
            "dc_coverage90": float(np.mean([lo <= e["drape_coefficient"]["observed"] <= hi for e in per_image])),
            "node_within1": float(np.mean([abs(e["node_count"]["predicted_mode"] - e["node_count"]["observed"]) <= 1
                                           for e in per_image])),
            "amplitude_bias_m": float(np.mean([e["node_amplitude_m"]["predicted_mean"] - e["node_amplitude_m"]["observed"]
                                               for e in per_image])),
            "amplitude_coverage90": float(np.mean([amp_lo <= e["node_amplitude_m"]["observed"] <= amp_hi
                                                   for e in per_image]))}
    mean["mse_best_of"] = {key: float(np.mean([e["mse_best_of"][key] for e in per_image]))
                           for key in per_image[0]["mse_best_of"]}
    if meshes:
        mean["hausdorff_m"] = float(np.mean([e["hausdorff_m"] for e in per_image]))
    return {"preset": preset_or_path if isinstance(preset_or_path, str) else None, "model": kind, "samples": n,
            "failed_samples": len(failed),
            "placement_noise": {"velocity_m_s": predictive.placement[0], "angular_modes": predictive.placement[1]},
            "forward": predictive.forward, "mesh_level": predictive.level, "images": per_image, "mean": mean}
