"""A Bayesian last layer for the hybrid model: train the network, fix its hidden layer,
sample its output weights with the physics.

NUTS over every weight of a tanh network saturates its trees: the record constrains the
network at a few dozen voltage pairs, so most weight directions form curved, nearly flat
valleys (and a funnel between each output weight and its unit's input weights).  The
standard way out in Bayesian deep learning is to be Bayesian in the last layer only
(Kristiadi et al. 2020; Daxberger et al. 2021, "Laplace Redux"): with the hidden layer
fixed, the network's torque is *linear* in its output weights, ``T = sum_j w_j phi_j(q)``
with fixed features ``phi_j``, and the joint posterior of those weights and the physics
is close to Gaussian.  The price: the features are a point estimate, so the band covers
the uncertainty of the torque's *amplitudes* over those features, not of their shapes.

:func:`last_layer_setup`:

1. the base model (the hybrid without its networks) gets its MAP on the training window,
   started from the caller's guesses, the shipped fit of the rig record
   (:data:`heli_uq.model.RIG_FIT`) and :data:`BASE_COLD_STARTS` more starts.  Two cold
   starts alone are not enough: with ``m`` fixed (plain log coordinates instead of the
   inertia-ratio ones) both ended in a basin with V = 3.1 rad^2 on a 20 s synthetic record
   (3e-4 from the rig fit), and training and Laplace from there failed;
2. :func:`heli_uq.inference.train` fits the hybrid jointly from there (Adam, then L-BFGS
   on V, as in the paper);
3. the hidden weights and biases (``nn_W_*``, ``nn_b_*``) are fixed at the trained values
   in the priors; the trained point is the MAP search's first guess.

Layer 7 (uses the inference layer and the model; called by
:func:`heli_uq.output.sample_posterior`).
"""

from __future__ import annotations

from heli_uq.inference import prepare_start, train
from heli_uq.model import RIG_FIT
from heli_uq.model.prior import Prior
from heli_uq.model.spec import with_effects
from heli_uq.output.network import network_terms
from heli_uq.probability import PriorSet, make_problem

__all__ = ["last_layer_setup", "NETWORK_POSTERIORS"]

#: What ``sample_posterior(network_posterior=...)`` samples of a network.
NETWORK_POSTERIORS = ("full", "last-layer")
#: Starts of the base model's MAP beyond the guesses (module docstring).
BASE_COLD_STARTS = 2


def last_layer_setup(record, train_window, test_window, *, model, priors: PriorSet, error: str,
                     substeps=None, seed: int = 0, guesses=(),
                     log=None) -> tuple[PriorSet, list[dict], dict]:  # fmt: skip
    """Priors with the networks' hidden layers fixed at trained values (module docstring).

    ``guesses``: parameter dicts [SI] the base model's MAP starts from first (names the
    base model lacks are ignored), before the rig fit and the cold starts.

    Returns
    -------
    priors : PriorSet
        ``priors`` with every ``nn_W_*`` and ``nn_b_*`` fixed.
    guesses : list of dict
        The trained parameters [SI], the MAP's first start.
    info : dict
        ``base_map_value``, ``v_base``, ``v_trained`` [rad^2] and ``train_seconds``.
    """
    log = log or (lambda text: None)
    base = with_effects(model, lambda e: e["effect"] != "neural_torque", where="last_layer_setup")
    base_priors = PriorSet({n: priors.params[n] for n in base.names}, dict(priors.x0), dict(priors.noise))
    base_problem = make_problem(record, train_window, test_window, model=base, priors=base_priors,
                                error=error, substeps=substeps)  # fmt: skip
    log("last layer: MAP of the base model")
    starts = (*guesses, RIG_FIT)
    params, x0 = prepare_start(base_problem, n_starts=len(starts) + BASE_COLD_STARTS, seed=seed,
                               guesses=starts).map_point()  # fmt: skip
    problem = make_problem(record, train_window, test_window, model=model, priors=priors, error=error,
                           substeps=substeps)  # fmt: skip
    log("last layer: joint training of the hybrid (Adam, then L-BFGS on V)")
    fitted = train(problem, params, x0, trainable="all")
    hidden = [p.name for t in network_terms(problem.model) for p in t.parameters()
              if p.bare.startswith(("nn_W_", "nn_b_"))]  # fmt: skip
    fixed = priors.updated(problem.model, {n: Prior("fixed", float(fitted.params[n])) for n in hidden},
                           where="last layer")  # fmt: skip
    guess = dict(fitted.params)
    info = {"v_base": float(fitted.v_start), "v_trained": float(fitted.v), "train_seconds": fitted.seconds}
    return fixed, [guess], info
