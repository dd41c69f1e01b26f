# %% [markdown]
# # heli_uq quickstart
# Simulate the paper's model on the rig record, differentiate the loss, and add a named
# effect.  (jupytext percent format: open in Jupyter with jupytext, or run as a script.)
# Units: angles in rad, rates in rad/s, voltages in V, parameters in SI (paper Table 2).

# %%
from _setup import rig_or_synthetic  # noqa: I001  (first: it sets up warnings)

import jax
import jax.numpy as jnp

import heli_uq
from heli_uq.simulation import default_substeps
from heli_uq.simulation.reference import solver_error

exp, _, _ = rig_or_synthetic()  # HELI_UQ_DATA, a checked download, or the synthetic record
print(f"{exp.source}: {exp.n} samples, dt = {exp.dt} s")
x0 = jnp.array([exp.y[0, 0], exp.y[0, 1], 0.0, 0.0])  # first measured angles, at rest

# %% [markdown]
# Forward solve with the paper's Table 1 parameters and the loss V (Eq. 1) [rad^2].

# %%
ys = heli_uq.simulate(heli_uq.TABLE1, x0, exp.u, exp.dt)
print("V(Table 1) =", float(heli_uq.loss_v(ys, exp.y)))


# %% [markdown]
# Gradient of V with respect to every parameter and the initial state (discrete adjoint).


# %%
def loss(p, x):
    return heli_uq.loss_v(heli_uq.simulate(p, x, exp.u, exp.dt), exp.y)


g_params, g_x0 = jax.jit(jax.grad(loss, argnums=(0, 1)))(heli_uq.TABLE1, x0)
for name, value in g_params.items():
    print(f"dV/d{name:14s} = {float(value): .4g}")

# %% [markdown]
# A model with a named effect: Coulomb friction in yaw.  Its parameter is named with the
# axis (``F_c_yaw``); missing values take the model's defaults ("no effect").  The sharp
# friction law is stiff, so the solver takes several RK4 substeps per sample; check the
# choice against the adaptive stiff reference on the first 5 s.

# %%
model = heli_uq.parse_effects("yaw:coulomb_friction")
print(model.label)
for par in model.parameters():
    print(f"  {par.name:14s} [{par.unit:10s}] default {par.default:<8g} prior {par.prior.describe()}")
params = {**heli_uq.TABLE1, "F_c_yaw": 0.004}
substeps = default_substeps(model, params, exp.dt, thetas=exp.y[:, 0])
ys_f = heli_uq.simulate(params, x0, exp.u, exp.dt, model=model, substeps=substeps)
print(f"V(Table 1 + F_c_yaw = 0.004 N m, {substeps} substeps) =", float(heli_uq.loss_v(ys_f, exp.y)))
short = exp.window(float(exp.t[0]), float(exp.t[0]) + 5.0)
err = solver_error(params, x0, short.u, short.dt, model=model, substeps=substeps)
print(f"solver error vs reference, first 5 s: {err:.1e} rad")

# %% [markdown]
# The posterior of such a model: ``heli-uq sample --data experimental --effects
# yaw:coulomb_friction --error iid --out DIR`` (or
# :func:`heli_uq.output.sample_posterior` from Python).
