# %% [markdown]
# # Discovery: which physical effect is missing?
# `discover` fits the base model, finds where the data leave its predictive band, learns
# the torque the data imply, fits each named effect of the vocabulary as a parametric
# term, ranks them by a blocked held-out predictive score with its standard error, adds
# the winner (or says `none`) and refits with NUTS.  The same as
# `heli-uq discover DATA --train a:b --test c:d --out DIR`.
#
# Size: `small` (the tests) hides a yaw torque offset in a 30 s synthetic rig-like record
# and tries three candidates with a smoke-sized refit, so the known answer can be checked;
# `full` (default) runs the rig record with the quick budget, every effect on both axes
# and pairs (`--max-effects 2`): about half an hour on 2 cores.

# %%
from _setup import SIZE, SMALL, rig_or_synthetic  # noqa: I001  (first: it sets up warnings)

import json
import pathlib

from IPython.display import Image, Markdown, display

from heli_uq.discovery import BUDGETS, Budget, discover
from heli_uq.model import RIG_FIT, RIG_FIT_X0, build_model
from heli_uq.simulation import synthetic_experiment
from heli_uq.simulation.synthetic import ENCODER_QUANTUM

#: The hidden effect of the small size: a constant yaw torque [N m].
HIDDEN = {"T_0_yaw": -0.04}
if SMALL:
    record = synthetic_experiment({**RIG_FIT, **HIDDEN}, RIG_FIT_X0, duration=30.0, inputs="rig_steps",
                                  noise_std=(0.003, 0.008), seed=11, model=build_model(["yaw:torque_offset"]),
                                  quantum=ENCODER_QUANTUM)
    train, test = (0.0, 21.0), (21.0, 30.0)
    options = dict(budget=Budget(n_starts=2, cold_starts=0, draws=40, pair_top=0, chains=2, warmup=100,
                                 samples=100, max_tree_depth=5),
                   candidates=("yaw:torque_offset", "yaw:quadratic_drag", "pitch:torque_offset"),
                   scheduler="serial")
    print(f"size {SIZE}: synthetic record, hidden {HIDDEN}")
else:
    record, train, test = rig_or_synthetic()
    options = dict(budget=BUDGETS["quick"], max_effects=2)
    print(f"size {SIZE}: {record.source}")

# %%
out = pathlib.Path("out/discovery")
result = discover(record, out, train=train, test=test, seed=0, **options)

# %% [markdown]
# ## The answer
# `discovery.json` names the effect and its axis, the parameters with 95 % intervals, and
# the gap before and after (RMSE, V and 90 % coverage on train and test).

# %%
print(result["decision"])
print(json.dumps({k: result[k] for k in ("effect", "axis", "parameters")}, indent=1))
for when in ("gap_before", "gap_after"):
    print(when, json.dumps(result[when]))

# %% [markdown]
# ## Where the base model failed, and the candidates' scores
# Residuals by time, input segment and state; then each candidate's held-out score
# against the base with its standard error (the margin a candidate must clear is
# calibrated on records without a hidden effect).

# %%
for name in ("residuals.png", "candidates.png", "bands_before.png", "bands_after.png"):
    display(Image(str(out / name)))

# %% [markdown]
# `report.md` is the text a person reads first:

# %%
display(Markdown((out / "report.md").read_text()))
