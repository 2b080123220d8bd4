# %% [markdown]
# # The paper's 7-DoF arm, from Python
#
# Simulate the skin of the arm of the paper's Fig. 6, find its kinematic tree, calibrate it, and
# check the result on poses it has not seen. Run it as a script (`python examples/paper_arm.py`)
# or cell by cell in Jupyter or VS Code; it writes its files to a temporary directory.

# %%
import tempfile
from pathlib import Path

import numpy as np

import skincal

out = Path(tempfile.mkdtemp(prefix="skincal-example-"))
data = skincal.simulate("paper-7dof", seed=1)  # 20 random poses, uniform ±0.01 g noise
print(data)

# %% [markdown]
# ## Structure: which DoF moves which segment

# %%
structure = skincal.explore(data)
print(structure)
segments, joints = structure.activity_labels
print("      " + " ".join(f"{j:>3}" for j in joints))
for name, row in zip(segments, structure.activity):
    print(f"{name:>5} " + " ".join("  ■" if x else "  ·" for x in row))

# %% [markdown]
# ## Kinematics: the DH+2 table with standard deviations

# %%
model = skincal.calibrate(data, structure)
(limb,) = model.limbs
print(f"limb {limb.name}: converged {limb.converged}, residual {limb.residual:.3f} σ")
dh = limb.dh["dof_dof"]
sd = limb.dh["dof_dof_sd"]
print("  row   a (mm)             alpha (°)")
for k in range(len(dh["a"])):
    print(
        f"  {k + 1:>3}   {1e3 * dh['a'][k]:7.2f} ± {1e3 * sd['a'][k]:4.2f}"
        f"     {np.degrees(dh['alpha'][k]):8.3f} ± {np.degrees(sd['alpha'][k]):5.3f}"
    )
for su, (position, orientation) in limb.su_sd.items():
    free = limb.su_undetermined.get(su)
    note = (
        f" (and {len(free['position'])} position direction(s), {len(free['orientation'])} axis(es) no reading determines)"
        if free
        else ""
    )
    print(f"  {su}: position ± {1e3 * position:.2f} mm, orientation ± {np.degrees(orientation):.3f}°{note}")

# %% [markdown]
# ## Held-out poses: the same skin, noise-free readings at 20 other poses

# %%
held = skincal.simulate("paper-7dof", seed=1, pose_seed=99, noise=0.0, structure=False)
check = model.validate(held)
print(f"held-out RMS: static {check.static_rms:.4f} m/s², dynamic {check.dynamic_rms:.4f} m/s²")
static, dynamic = model.predict(held.training.poses, held.training.pattern)
errors = np.linalg.norm(static - held.training.static, axis=2)  # poses × SUs
print("static error per SU (RMS, m/s²):", np.round(np.sqrt(np.mean(errors**2, axis=0)), 4))
assert check.static_rms < 0.06 and check.dynamic_rms < 0.03

# %% [markdown]
# ## Files the CLI reads: `skincal report`, `predict`, `check-urdf` take them as they are

# %%
data.save(out / "measurements.json")
structure.save(out / "structure.json")
model.save(out / "model.json")
(out / "arm.urdf").write_text(model.to_urdf())
print("wrote", ", ".join(sorted(p.name for p in out.iterdir())), "to", out)
