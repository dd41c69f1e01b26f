"""Probability: priors, sampling coordinates, error models, the one likelihood, the problem
and the numpyro model.

Layer 4 (imports data, model and simulate).
"""

from heli_uq.probability.coordinates import Coordinates as Coordinates
from heli_uq.probability.likelihood import log_likelihood as log_likelihood
from heli_uq.probability.likelihood import loss_v as loss_v
from heli_uq.probability.likelihood import pointwise_log_likelihood as pointwise_log_likelihood
from heli_uq.probability.likelihood import whitened_residuals as whitened_residuals
from heli_uq.probability.noise import ERROR_MODELS as ERROR_MODELS
from heli_uq.probability.noise import ar1_noise as ar1_noise
from heli_uq.probability.noise import marginal_sd as marginal_sd
from heli_uq.probability.numpyro_model import heli_model as heli_model
from heli_uq.probability.priors import PriorSet as PriorSet
from heli_uq.probability.priors import load_priors_json as load_priors_json
from heli_uq.probability.priors import parse_prior_option as parse_prior_option
from heli_uq.probability.problem import Problem as Problem
from heli_uq.probability.problem import check_split as check_split
from heli_uq.probability.problem import make_problem as make_problem

__all__ = ["Coordinates", "log_likelihood", "loss_v", "pointwise_log_likelihood",
           "whitened_residuals", "ERROR_MODELS", "ar1_noise", "marginal_sd", "heli_model", "PriorSet",
           "load_priors_json", "parse_prior_option", "Problem", "check_split", "make_problem"]  # fmt: skip
