# %% [markdown]
# # heli_uq quickstart
# Simulate the paper's model on the rig record and differentiate the loss.
# (jupytext percent format: open in Jupyter with jupytext, or run as a script.)

# %%
import jax
import jax.numpy as jnp

import heli_uq
from heli_uq.data import load_data

exp = load_data("experimental")  # HELI_UQ_DATA or a checked download
x0 = jnp.array([exp.y[0, 0], exp.y[0, 1], 0.0, 0.0])

# %% [markdown]
# Forward solve with the paper's Table 1 parameters and the loss V (Eq. 1).

# %%
ys = heli_uq.simulate(heli_uq.TABLE1, x0, exp.u, exp.dt)
print("V(Table 1) =", float(heli_uq.loss_v(ys, exp.y)))


# %% [markdown]
# Gradient of V with respect to every parameter and the initial state.


# %%
def loss(p, x):
    return heli_uq.loss_v(heli_uq.simulate(p, x, exp.u, exp.dt), exp.y)


g_params, g_x0 = jax.jit(jax.grad(loss, argnums=(0, 1)))(heli_uq.TABLE1, x0)
for name, value in g_params.items():
    print(f"dV/d{name:14s} = {float(value): .4g}")
