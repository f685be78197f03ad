"""The evolving-population MCMC filter (Bhaskar and Mihaylova 2011, section 3.1, Algorithms 1-2).

One population of N particles per target. Each frame:

1. Sampling (Algorithm 1 (2)): draw every particle from the transition prior (:mod:`.motion`),
   then move the populations with the genetic kernel G_k -- structure-constrained crossover between
   random pairs and per-component mutation (projected back into the structure); weights
   w_k = w_{k-1} L(z_k | x_k) (eq. 6, the genetic proposal is treated as the prior), normalised in logs.
2. Resampling (Algorithm 1 (3)), for every population whose ESS = 1 / sum W^2 <= N_thr1: residual
   resampling, then ``mcmc_iterations`` population-MCMC sweeps (Algorithm 2): a mutation MH move for
   every particle, then either a crossover MH move for random pairs within every population or, with
   probability ``exchange_prob``, an exchange MH move (eq. 8) between the particles of two randomly
   chosen populations. The MCMC target of population t is pi_t(x) ∝ L_t(z_k | x) G_t(x), with G_t
   the Gaussian fit to the population's predicted particles (the transition prior, moment-matched):
   parts and axes independent, but each part's position and velocity along an axis correlated as in
   the population (``couple_velocity``), and a mutation moves a part's velocity with its position by
   the population's regression slope -- otherwise every resample-move would discard what the
   population knows about speed. The moves leave pi_t invariant, so the moved particles carry equal
   weights (Algorithm 1 (a3): the recomputed weights are uniform).

Estimates are the weighted means after the resample-move step.
"""

from __future__ import annotations

import numpy as np

from ..tracking import resampling
from .appearance import PartEvidence
from .genetic import crossover, exchange, mh_accept, mutate
from .likelihood import AssociationTerms
from .state import MultiTrackState
from .tracker import MultiTargetFilter


class EPMCMCFilter(MultiTargetFilter):
    """``step(frame_time, evidence) -> MultiTrackState``."""

    def _genetic_proposal(self) -> None:
        """Global evolution in the sampling step: crossover of random pairs, then projected mutation."""
        ev = self.config.evolution
        rng = self.rngs["genetic"]
        t_n, n = self.log_w.shape
        for t in range(t_n):
            perm = rng.permutation(n)
            a, b = perm[0: n - n % 2: 2], perm[1: n - n % 2: 2]
            ca, cb, _ = crossover(self.particles[t, a], self.particles[t, b], self.body, ev.crossover_prob, rng)
            self.particles[t, a], self.particles[t, b] = ca, cb
            h = self.targets.height[t]
            self.particles[t], _ = mutate(self.particles[t], self.body, h, ev.mutation_prob_position,
                                          ev.mutation_prob_velocity, ev.mutation_sigma, ev.mutation_sigma * h, rng,
                                          project=True)  # fmt: skip

    def _fit_prior(self) -> None:
        """Moments of the predicted populations: mean (T, P, 4), std (T, P, 4) floored at
        ``prior_floor``, and the correlation (T, P, 2) of each part's position with its velocity
        along each axis (0 unless ``couple_velocity``; capped at 0.95 in size)."""
        ev = self.config.evolution
        w = self.weights()
        m = np.einsum("tn,tnpk->tpk", w, self.particles)
        d = self.particles - m[:, None]
        var = np.einsum("tn,tnpk->tpk", w, d * d)
        std = np.sqrt(np.maximum(var, ev.prior_floor**2))
        rho = np.zeros(m.shape[:-1] + (2,))
        if ev.couple_velocity:
            cov = np.einsum("tn,tnpk->tpk", w, d[..., :2] * d[..., 2:])
            rho = np.clip(cov / (std[..., :2] * std[..., 2:]), -0.95, 0.95)
        self._prior_mean, self._prior_std, self._prior_rho = m, std, rho
        # regression of velocity on position: E[v | x] moves by rho s_v / s_x per px
        self._velocity_gain = rho * std[..., 2:] / std[..., :2]

    def _log_prior(self, x: np.ndarray, model: np.ndarray) -> np.ndarray:
        """(K, N) log of the Gaussian fit to the predicted populations ``model`` at configurations
        (K, N, P, 4): independent parts and axes, each axis a bivariate (position, velocity) normal
        with correlation rho."""
        z = (x - self._prior_mean[model][:, None]) / self._prior_std[model][:, None]
        rho = self._prior_rho[model][:, None]
        zx, zv = z[..., :2], z[..., 2:]
        q = (zx * zx - 2 * rho * zx * zv + zv * zv) / (1 - rho * rho)
        return -0.5 * np.sum(q, axis=(-1, -2))

    def _log_target(self, x: np.ndarray, model: np.ndarray, evidence: PartEvidence, terms: AssociationTerms) -> np.ndarray:
        return self.log_likelihood(x[..., :2], model, evidence, terms) + self._log_prior(x, model)

    def step(self, frame_time: float, evidence: PartEvidence) -> MultiTrackState:
        if self.advance(frame_time):
            self._genetic_proposal()
        self._fit_prior()
        meas, terms, ll, w, n_eff, moved = self.weigh(evidence)
        acceptance: dict = {}
        if moved.any():
            acceptance = self._resample_move(np.flatnonzero(moved), w, ll, evidence, terms)
        return self.finish(frame_time, meas, terms, n_eff, moved, acceptance)

    def _resample_move(self, pops: np.ndarray, w: np.ndarray, ll: np.ndarray, evidence: PartEvidence,
                       terms: AssociationTerms) -> dict:
        """Residual resampling and population-MCMC sweeps (Algorithm 2) of populations ``pops``;
        ``ll`` (T, N): the particles' log-likelihoods from :meth:`weigh`, which the resampled copies
        keep (no second evidence query for them)."""
        ev = self.config.evolution
        n = self.n_particles
        scheme = resampling.get_scheme(self.config.resampling)
        kept = []
        for t in pops:
            idx = scheme(w[t], self.rngs["resample"])
            self.particles[t] = self.particles[t, idx]
            self.log_w[t] = -np.log(n)
            kept.append(ll[t, idx])
        rng = self.rngs["mcmc"]
        x = self.particles[pops]
        lp = np.stack(kept) + self._log_prior(x, pops)  # = self._log_target(x, pops, evidence, terms)
        counts = {k: [0, 0] for k in ("mutation", "crossover", "exchange")}
        for _ in range(ev.mcmc_iterations):
            # (a) mutation, one MH move per particle
            prop = np.empty_like(x)
            ok = np.empty(x.shape[:2], bool)
            for i, t in enumerate(pops):
                h = self.targets.height[t]
                prop[i], ok[i] = mutate(x[i], self.body, h, ev.mutation_prob_position, ev.mutation_prob_velocity,
                                        ev.mutation_sigma, ev.mutation_sigma * h, rng, project=False,
                                        velocity_gain=self._velocity_gain[t])  # fmt: skip
            lp_prop = self._log_target(prop, pops, evidence, terms)
            acc = mh_accept(np.where(ok, lp_prop - lp, -np.inf), rng)
            x[acc], lp[acc] = prop[acc], lp_prop[acc]
            counts["mutation"][0] += int(acc.sum())
            counts["mutation"][1] += acc.size
            # (b) exchange between two populations, or crossover within each
            if len(pops) >= 2 and rng.random() < ev.exchange_prob:
                i, j = rng.choice(len(pops), size=2, replace=False)
                perm = rng.permutation(n)
                xi, xj = x[i], x[j, perm]
                cross = self._log_target(np.stack([xj, xi]), pops[[i, j]], evidence, terms)  # pi_i(x_j), pi_j(x_i)
                new_i, new_j, acc = exchange(xi, xj, lp[i], cross[0], cross[1], lp[j, perm], rng)
                lp_i, lp_j = np.where(acc, cross[0], lp[i]), np.where(acc, cross[1], lp[j, perm])
                x[i], lp[i] = new_i, lp_i
                x[j, perm], lp[j, perm] = new_j, lp_j
                counts["exchange"][0] += int(acc.sum())
                counts["exchange"][1] += acc.size
            elif self.body.n_parts > 1:
                perm = rng.permutation(n)
                a, b = perm[0: n - n % 2: 2], perm[1: n - n % 2: 2]
                ca, cb, did = zip(*(crossover(x[i, a], x[i, b], self.body, ev.crossover_prob, rng) for i in range(len(pops))))
                ca, cb, did = np.stack(ca), np.stack(cb), np.stack(did)
                lps = self._log_target(np.concatenate([ca, cb], axis=1), pops, evidence, terms)
                lpa, lpb = lps[:, : len(a)], lps[:, len(a):]
                acc = mh_accept(np.where(did, lpa + lpb - lp[:, a] - lp[:, b], -np.inf), rng)
                for i in range(len(pops)):
                    k = acc[i]
                    x[i, a[k]], x[i, b[k]] = ca[i, k], cb[i, k]
                    lp[i, a[k]], lp[i, b[k]] = lpa[i, k], lpb[i, k]
                counts["crossover"][0] += int(acc.sum())
                counts["crossover"][1] += int(did.sum())
        self.particles[pops] = x
        return {k: a / b for k, (a, b) in counts.items() if b > 0}
