"""Inference: the log density, least squares and MAP, the Laplace approximation, NUTS and
emcee, with chunked resumable output; point training of hybrid models (Adam, L-BFGS).

Layer 5 (imports data, model, simulation, probability and the base modules, e.g.
:mod:`heli_uq.provenance`).
"""

from heli_uq.inference.checkpoint import Checkpoint as Checkpoint
from heli_uq.inference.density import LogDensity as LogDensity
from heli_uq.inference.density import constrain_draws as constrain_draws
from heli_uq.inference.density import log_density_setup as log_density_setup
from heli_uq.inference.emcee_sampler import run_emcee as run_emcee
from heli_uq.inference.laplace_sampler import importance_resample as importance_resample
from heli_uq.inference.laplace_sampler import run_laplace as run_laplace
from heli_uq.inference.least_squares import least_squares_fit as least_squares_fit
from heli_uq.inference.level_scale import level_scaled_covariance as level_scaled_covariance
from heli_uq.inference.levenberg import masked_least_squares as masked_least_squares
from heli_uq.inference.manifest import run_manifest as run_manifest
from heli_uq.inference.map import MapResult as MapResult
from heli_uq.inference.map import find_map as find_map
from heli_uq.inference.map import laplace as laplace
from heli_uq.inference.multistart import start_parameters as start_parameters
from heli_uq.inference.nuts import TARGET_ACCEPT as TARGET_ACCEPT
from heli_uq.inference.nuts import resume_obstacle as resume_obstacle
from heli_uq.inference.nuts import run_nuts as run_nuts
from heli_uq.inference.sampler_run import SamplerRun as SamplerRun
from heli_uq.inference.settle import settle_edge as settle_edge
from heli_uq.inference.start import Start as Start
from heli_uq.inference.start import prepare_start as prepare_start
from heli_uq.inference.train import Training as Training
from heli_uq.inference.train import train as train

SAMPLERS = ("nuts", "emcee", "laplace")

__all__ = ["Checkpoint", "LogDensity", "constrain_draws", "log_density_setup", "run_emcee",
           "masked_least_squares", "MapResult", "find_map", "laplace", "TARGET_ACCEPT",
           "SamplerRun", "run_nuts", "resume_obstacle", "run_laplace", "importance_resample", "Start",
           "least_squares_fit", "prepare_start", "start_parameters", "SAMPLERS", "run_manifest", "train",
           "Training", "level_scaled_covariance", "settle_edge"]  # fmt: skip
