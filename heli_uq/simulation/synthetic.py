"""Seeded synthetic records: simulate a model on random voltage staircases, add noise.

Used as the offline default of the main job and as records with a known truth in the
tests (parameter recovery, hidden effects).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from heli_uq.data.record import Experiment
from heli_uq.errors import DataFormatError, ParameterError
from heli_uq.model.tables import TABLE1

__all__ = ["SYNTHETIC_PARAMS", "SYNTHETIC_X0", "STEP_RANGES", "STEP_HOLD", "step_inputs",
           "synthetic_experiment", "RIG_RANGES", "RIG_HOLD", "ENCODER_QUANTUM"]  # fmt: skip

#: Default parameters of :func:`synthetic_experiment` (fitted-looking values, paper Table 1).
SYNTHETIC_PARAMS: Mapping[str, float] = dict(TABLE1)
#: Default initial state ``(theta, psi, omega_theta, omega_psi)`` [rad, rad, rad/s, rad/s].
SYNTHETIC_X0 = (-0.5, 0.0, 0.0, 0.0)
#: Voltage ranges [V] of the random ``"steps"`` profile: ``(low, high)`` for u_theta, u_psi.
#: Chosen so that, with the Table 1 parameters, pitch stays in -50..-10 deg and yaw within a
#: turn or so, like the real record (u_theta 1.21-1.47 V, u_psi 0.48-1.57 V).  Above
#: u_theta ~1.48 V the Table 1 pitch torque exceeds the largest gravity torque and the
#: model (which has no pitch stops) loops over the top.
STEP_RANGES = ((1.0, 1.45), (0.4, 1.3))
#: Range [s] of the hold time of one step of the ``"steps"`` profile.
STEP_HOLD = (0.5, 3.0)
#: The rig record's voltage ranges [V] ``((u_theta), (u_psi))`` and segment lengths [s].
RIG_RANGES = ((1.22, 1.47), (0.45, 1.6))
RIG_HOLD = (3.0, 14.0)
#: Angle resolution [rad] of a 4096-count encoder, for quantised synthetic records.
ENCODER_QUANTUM = 2 * np.pi / 4096


def step_inputs(n: int, dt: float, rng: np.random.Generator, ranges=STEP_RANGES,
                hold=STEP_HOLD) -> np.ndarray:
    """Random piecewise-constant voltages, shape (n, 2) [V]: levels uniform in ``ranges``
    ``((lo, hi) for u_theta, (lo, hi) for u_psi)``, each held ``hold = (min, max)`` seconds."""
    low, high = np.array(ranges).T
    u = np.empty((n, 2))
    k = 0
    while k < n:
        steps = max(1, round(rng.uniform(*hold) / dt))
        u[k : k + steps] = rng.uniform(low, high)
        k += steps
    return u


def synthetic_experiment(
    params: Mapping[str, float] | None = None,
    x0: Sequence[float] | None = None,
    *,
    duration: float = 20.0,
    dt: float = 0.01,
    inputs: str | np.ndarray = "steps",
    noise_std: Sequence[float] = (0.002, 0.002),
    seed: int = 0,
    simulator: Callable | None = None,
    model=None,
    substeps: int | None = None,
    quantum: float | None = None,
) -> Experiment:
    """A seeded synthetic record: simulate the model and add Gaussian measurement noise.

    Parameters
    ----------
    params : mapping, optional
        Model parameters passed to *simulator*; default :data:`SYNTHETIC_PARAMS`.
    x0 : sequence of 4 floats, optional
        Initial state ``(theta, psi, omega_theta, omega_psi)`` [rad, rad/s]; default
        :data:`SYNTHETIC_X0`.
    duration : float
        Length [s]; N = round(duration/dt).  Ignored when *inputs* is an array.
    dt : float
        Sample time [s].
    inputs : {"steps", "rig_steps"} or array_like, shape (N, 2)
        ``"steps"``: random voltages in :data:`STEP_RANGES` held for random
        0.5-3 s segments; ``"rig_steps"``: in the rig record's ranges :data:`RIG_RANGES`,
        held 3-14 s (:data:`RIG_HOLD`).  An array: voltages ``[u_theta, u_psi]`` [V],
        zero-order held.
    noise_std : pair of float
        Standard deviations [rad] of the iid Gaussian noise on theta and psi.
    seed : int
        Seed of the numpy Generator drawing inputs and noise; same seed, same record.
    simulator : callable, optional
        ``simulator(params, x0, u, dt) -> (N, 4)`` states on the sample grid (e.g. an
        independent reference); default :func:`heli_uq.simulation.simulate` of ``model``.
    model : HeliModel, optional
        The model simulated by the default simulator (default: the paper's); ``params``
        may then name its effect parameters (e.g. ``F_c_yaw``).
    substeps : int, optional
        RK4 substeps of the default simulator (default: :func:`default_substeps` at
        ``params``, doubled for margin).
    quantum : float, optional
        Round the noisy angles to multiples of ``quantum`` [rad] (an encoder, e.g.
        :data:`ENCODER_QUANTUM`).

    Returns
    -------
    Experiment
        ``t = k*dt``, ``source = "synthetic(seed=...)"``.

    Raises
    ------
    ParameterError
        On invalid duration, dt, inputs or noise_std.
    DataFormatError
        If the simulation has the wrong shape or is not finite.
    """
    params = dict(SYNTHETIC_PARAMS if params is None else params)
    if simulator is None:
        simulator = _model_simulator(model, params, dt, substeps)
    x0 = np.array(SYNTHETIC_X0 if x0 is None else x0, dtype=float)
    if not (np.isfinite(dt) and dt > 0):
        raise ParameterError(f"dt: expected a finite number > 0, found {dt!r}")
    noise_std = np.array(noise_std, dtype=float)
    if noise_std.shape != (2,) or not np.all(np.isfinite(noise_std) & (noise_std >= 0)):
        raise ParameterError(f"noise_std: expected 2 finite numbers >= 0, found {noise_std}")
    rng = np.random.default_rng(seed)

    if isinstance(inputs, str):
        if inputs not in ("steps", "rig_steps"):
            raise ParameterError(f"inputs {inputs!r}: expected 'steps', 'rig_steps' or an (N, 2) "
                                 "array")  # fmt: skip
        n = round(duration / dt) if np.isfinite(duration) else 0
        if n < 2:
            raise ParameterError(f"duration {duration!r}: expected at least 2 samples of {dt} s")
        u = step_inputs(n, dt, rng) if inputs == "steps" else step_inputs(n, dt, rng, RIG_RANGES, RIG_HOLD)
    else:
        u = np.array(inputs, dtype=float)
        if u.ndim != 2 or u.shape[0] < 2 or u.shape[1] != 2 or not np.all(np.isfinite(u)):
            raise ParameterError(f"inputs: expected a finite (N, 2) array, N >= 2, "
                                 f"found shape {u.shape}")
        n = u.shape[0]

    states = np.asarray(simulator(params, x0, u, dt), dtype=float)
    if states.shape != (n, 4):
        raise DataFormatError(f"simulation: expected shape ({n}, 4), found {states.shape}")
    if not np.all(np.isfinite(states)):
        raise DataFormatError(f"simulation (seed={seed}): non-finite states, e.g. at "
                              f"t = {np.argmax(~np.all(np.isfinite(states), axis=1)) * dt} s")
    y = states[:, :2] + rng.normal(size=(n, 2)) * noise_std
    if quantum is not None:
        y = np.round(y / quantum) * quantum
    return Experiment(np.arange(n) * dt, u, y, dt, f"synthetic(seed={seed})")


def _model_simulator(model, params, dt, substeps):
    from heli_uq.model.heli_model import HeliModel
    from heli_uq.simulation.solver import simulate
    from heli_uq.simulation.stiffness import capped_substeps, default_substeps

    model = HeliModel() if model is None else model
    if substeps is None:
        substeps = capped_substeps(default_substeps(model, params, dt, margin=2.0), "a synthetic record")

    def run(p, x0, u, step):
        return simulate(p, x0, u, step, model=model, substeps=substeps)

    return run
