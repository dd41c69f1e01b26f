# %% [markdown]
# # Identifiability
# Which of the paper's parameters the record can tell apart: the structural rank of the
# output sensitivities and its named null space (the common scale of the inertias, gains
# and damping), the Fisher information, profile likelihoods, and prior-to-posterior
# contraction.  The same report as `heli-uq identifiability --data experimental --out DIR`.
#
# Size: `small` uses the first 20 s and 3 structural points; `full` (default) the whole
# record and 5 points (a few minutes).

# %%
from _setup import SIZE, SMALL, rig_or_synthetic  # noqa: I001  (first: it sets up warnings)

import pathlib

from IPython.display import Image, Markdown, display

from heli_uq.identifiability import identifiability_report

record, _, _ = rig_or_synthetic()
if SMALL:
    record = record.window(0.0, 20.0)
n_points = 3 if SMALL else 5
print(f"size {SIZE}: {record.n} samples, {n_points} structural points")

# %%
out = pathlib.Path("out/identifiability")
report = identifiability_report(record, out, n_points=n_points, seed=0)
structural = report["structural"]
print(f"structural rank {structural['rank']} of {structural['n_parameters']} coordinates")
for direction in structural["null_directions"]:
    print(f"  null direction {direction['key']}: {direction['description']}")

# %% [markdown]
# ## Do the views agree?
# Each null direction should have flat profiles and no contraction; each parameter's
# profile class should match its contraction.  One line per check:

# %%
for check in report["cross_check"]:
    print(("agree    " if check["agree"] else "DISAGREE ") + check["detail"])

# %% [markdown]
# ## The report
# `identifiability.md` is written for a person; its first section names the null
# directions and the identifiable combinations.

# %%
text = (out / "identifiability.md").read_text()
display(Markdown(text.split("## 2.")[0]))

# %%
for name in ("singular_values.png", "profiles.png", "contraction.png"):
    display(Image(str(out / name)))
