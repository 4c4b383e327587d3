"""The trainer's numerical core, native (drapelab_native.infer, native/src/infer), in the fit's numpy shapes.

A fit's parameters theta are a dict of arrays: "mu" ((3, 5); heter (E, 3, 5)), "eta" (bdp, (3, 5)) in log units,
and with fitted effects "effect_mu" and "effect_eta" (stochastic families) of shape (P,). Bending tables are
(3, 5) (homo) or (E, 3, 5) in N m. The native side takes flat blocks and (rows, 15) tables; this module does the
reshaping, nothing else: the families' reparameterisation and prior, the effect block, the ELBO assembly, Adam
and the clip rule are native (finite-difference tested in tests/native/infer).
"""
import numpy as np

from . import tables
from ._native import native

__all__ = ["Family", "EffectBlock", "effect_block", "effect_draw", "Draw", "assemble_elbo", "adam_step", "clip_threshold", "kl_divergence"]

BEND_SHAPE = tables.BEND_SHAPE
_core = native.infer


def _flat(theta):
    return {k: np.ascontiguousarray(v, dtype=np.float64).reshape(-1) for k, v in theta.items()}


def _like(flat, like):
    """Flat blocks back in the shapes of `like`'s blocks."""
    return {k: np.asarray(v).reshape(np.shape(like[k])) for k, v in flat.items()}


def _rows(table):
    return np.ascontiguousarray(table, dtype=np.float64).reshape(-1, _core.BEND_ENTRIES)


class Family:
    """A variational family of the bending table ("homo", "heter" or "bdp"; see infer.py's module doc):
    per_element (one table per bending edge), stochastic (draws use noise)."""

    def __init__(self, name):
        self.native = _core.Family(name)
        self.name = self.native.name
        self.per_element = self.native.per_element
        self.stochastic = self.native.stochastic

    def initial(self, log_bend0, num_edges, init_std):
        """theta at the starting log table (3, 5); init_std: the starting posterior sd (stochastic families)."""
        flat = self.native.initial(np.asarray(log_bend0, dtype=float).reshape(-1), int(num_edges), float(init_std))
        return {k: v.reshape(BEND_SHAPE if v.size == _core.BEND_ENTRIES else (-1,) + BEND_SHAPE).copy()
                for k, v in flat.items()}

    def tables(self, theta, num_edges, noise=None):
        """Bending tables (N m): (3, 5) when one table serves every edge, else (E, 3, 5); noise (E, 3, 5)."""
        t = self.native.tables(_flat(theta), int(num_edges), None if noise is None else _rows(noise))
        return t.reshape(BEND_SHAPE if not self.per_element else (-1,) + BEND_SHAPE)

    def posterior(self, theta):
        """(mean, sd) of the log table per entry, (3, 5) each (heter: across edges)."""
        mean, sd = self.native.posterior(_flat(theta))
        return mean.reshape(BEND_SHAPE), sd.reshape(BEND_SHAPE)


EffectBlock = _core.EffectBlock  # EffectBlock(off, lower, upper, prior_scale): the fitted effect parameters


def effect_block(plan):
    """The native block of a fit_effects.EffectPlan's fitted parameters (None when it fits none)."""
    if not plan.size:
        return None
    return _core.EffectBlock(plan.off, plan.lower, plan.upper, plan.prior_scale)


def effect_draw(block, theta, noise=None):
    """(values clipped to the bounds, mask of those inside them) of one draw of the fitted effects:
    effect_mu (+ softplus(effect_eta) noise)."""
    return block.draw({k: np.asarray(theta[k], dtype=float) for k in ("effect_mu", "effect_eta") if k in theta},
                      None if noise is None else np.asarray(noise, dtype=float))


def Draw(data, table_gradient, tables, noise=None, effect_gradient=None, effect_noise=None):
    """What one drape gives the ELBO: its data term, dL/dB (shaped like its tables), the tables, the family's
    noise, dL/d(fitted effect values) and the effects' noise."""
    return _core.Draw(float(data), _rows(table_gradient), _rows(tables), None if noise is None else _rows(noise),
                      None if effect_gradient is None else np.asarray(effect_gradient, dtype=float),
                      None if effect_noise is None else np.asarray(effect_noise, dtype=float))


def assemble_elbo(family, effects, theta, draws, clip, prior_mu, prior_sigma, kl_weight, effect_prior_weight):
    """(terms {"loss", "data", "kl", "grad_norm", "clip"}, gradient dict shaped like theta) of the negative ELBO
    over the draws (infer/elbo.hpp): the data gradient capped at norm `clip` (None: not) before the prior's."""
    terms, grads = _core.assemble_elbo(family.native, effects, _flat(theta), list(draws),
                                       None if clip is None else float(clip),
                                       np.asarray(prior_mu, dtype=float).reshape(-1), float(prior_sigma),
                                       float(kl_weight), float(effect_prior_weight))
    return terms, _like(grads, theta)


def adam_step(theta, grads, state, t, learning_rates, lr_scale, beta1, beta2, epsilon, effects=None):
    """One Adam step t (1-based) on the blocks of grads (infer/adam.hpp). state: {block: {"m", "v"}}, updated in
    place; learning rates per block (a number or one per entry). Returns the new theta (the blocks of theta that
    grads does not hold unchanged; effect_mu projected into the effects' bounds)."""
    flat, m, v = _core.adam_step(
        _flat(theta), _flat(grads), _flat({k: state[k]["m"] for k in grads}), _flat({k: state[k]["v"] for k in grads}),
        int(t), {k: np.atleast_1d(np.asarray(learning_rates[k], dtype=float)).reshape(-1) for k in grads},
        float(lr_scale), float(beta1), float(beta2), float(epsilon), effects)
    for k in grads:
        state[k] = {"m": m[k].reshape(np.shape(theta[k])), "v": v[k].reshape(np.shape(theta[k]))}
    return _like(flat, theta)


def kl_divergence(mu, sigma, mu0, sigma0):
    """KL(N(mu, sigma^2) || N(mu0, sigma0^2)) summed over entries, and its gradients (d/dmu, d/dsigma) shaped
    like mu; sigma0 a number or an array like mu."""
    mu = np.asarray(mu, dtype=float)
    value, d_mu, d_sigma = _core.kl_divergence(mu.reshape(-1), np.broadcast_to(sigma, mu.shape).reshape(-1).astype(float),
                                               np.broadcast_to(mu0, mu.shape).reshape(-1).astype(float),
                                               np.atleast_1d(np.asarray(sigma0, dtype=float)).reshape(-1))
    return float(value), d_mu.reshape(mu.shape), d_sigma.reshape(mu.shape)


def clip_threshold(norms, factor, window, min_epochs):
    """factor x the median of the first `window` norms; None while fewer than min_epochs, or when factor <= 0."""
    return _core.clip_threshold([float(n) for n in norms], float(factor), int(window), int(min_epochs))
