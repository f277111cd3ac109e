"""What a focal-length error does to an AP and a LAT DRR of L3: what you would type in a notebook.

Run after `make python`:

    target/pyenv/bin/python examples/python/calibration_sensitivity.py [OUT.png] [DF_PX]

It builds the L3 phantom, renders AP and LAT thickness DRRs with the true K and with K perturbed by
Δf (default 500 px), measures Dice per structure and landmark shifts, and saves a figure.
"""

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import spinedrr  # noqa: E402

out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("out/python_example.png")
df = float(sys.argv[2]) if len(sys.argv) > 2 else 500.0

# 1. Anatomy and geometry: the phantom's meshes with their μ, the default C-arm.
l3 = spinedrr.phantom("L3")
renderer = spinedrr.Renderer(l3.scene)  # build once, render many views
carm = spinedrr.CArm.default()
delta = spinedrr.Perturbation(df=df)

results = {}
for name in ("ap", "lat"):
    true_view = carm.view(name)
    pert_view = true_view.perturbed(delta)
    # 2. Render with the true and the perturbed K (float32 arrays, masks per structure).
    ref, ref_masks = renderer.render(true_view, masks=True)
    pert, pert_masks = renderer.render(pert_view, masks=True)
    # 3. Metrics: Dice per structure and landmark shifts, the numbers `spinedrr compare` writes.
    pairs = {s: (ref_masks["structures"][s], pert_masks["structures"][s])
             for s in ref_masks["structures"] if s in pert_masks["structures"]}
    metrics = spinedrr.compare(ref, pert, masks=pairs, landmarks=l3.landmarks, views=(true_view, pert_view))
    results[name] = dict(ref=ref, pert=pert, view=true_view, pview=pert_view, metrics=metrics)
    shifts = [lm["shift_px"] for lm in metrics["landmarks"]]
    dice = {s["name"]: s["dice"] for s in metrics["silhouettes"]}
    print(f"{name.upper():3}  vertebra Dice {dice['vertebra']:.4f}   landmark shift mean {np.mean(shifts):5.2f} px, "
          f"max {np.max(shifts):5.2f} px   NCC {metrics['image']['ncc']:.4f}")

# 4. The figure: each view's DRR with reference and perturbed landmarks, then Dice and shifts.
fig, axes = plt.subplots(2, 2, figsize=(12, 10), layout="constrained")
names = list(l3.landmarks)
xyz = np.array([l3.landmarks[n] for n in names])
for col, name in enumerate(("ap", "lat")):
    r = results[name]
    ax = axes[0, col]
    ax.imshow(r["ref"], cmap="gray_r")
    ax.contour(r["pert"] > 0, levels=[0.5], colors="tab:orange", linewidths=0.8)
    a, b = r["view"].project(xyz), r["pview"].project(xyz)
    ax.scatter(a[:, 0], a[:, 1], s=14, c="tab:blue", label="true K")
    ax.scatter(b[:, 0], b[:, 1], s=14, c="tab:orange", marker="x", label=f"Δf = {df:g} px")
    for p, q in zip(a, b):
        ax.annotate("", xy=q, xytext=p, arrowprops=dict(arrowstyle="->", color="tab:red", lw=0.8))
    lo, hi = np.minimum(a, b).min(0) - 60, np.maximum(a, b).max(0) + 60
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(hi[1], lo[1])
    ax.set_title(f"{name.upper()}: DRR with true K; orange: silhouette with Δf", fontsize=10)
    ax.legend(loc="lower right", fontsize=8)

structures = [s["name"] for s in results["ap"]["metrics"]["silhouettes"]]
x = np.arange(len(structures))
ax = axes[1, 0]
for k, name in enumerate(("ap", "lat")):
    dice = {s["name"]: s["dice"] for s in results[name]["metrics"]["silhouettes"]}
    ax.bar(x + (k - 0.5) * 0.4, [1 - dice.get(s, np.nan) for s in structures], 0.4, label=name.upper())
ax.set_xticks(x, structures, rotation=45, ha="right")
ax.set_ylabel("1 − Dice")
ax.set_title("Silhouette change per structure")
ax.legend()

ax = axes[1, 1]
y = np.arange(len(names))
for k, name in enumerate(("ap", "lat")):
    shift = {lm["name"]: lm["shift_px"] for lm in results[name]["metrics"]["landmarks"]}
    ax.barh(y + (k - 0.5) * 0.4, [shift[n] for n in names], 0.4, label=name.upper())
short = [n.split("/")[-1] for n in names]
ax.set_yticks(y, short, fontsize=8)
ax.set_xlabel("landmark shift (px)")
ax.set_title("Landmark shifts")
ax.legend()

fig.suptitle(f"L3 phantom, focal-length error Δf = {df:g} px")
out.parent.mkdir(parents=True, exist_ok=True)
fig.savefig(out, dpi=110)
print(f"figure: {out}")
