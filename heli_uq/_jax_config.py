"""Enable float64 in JAX before any array is created (imported first by ``heli_uq``)."""

import jax

jax.config.update("jax_enable_x64", True)
