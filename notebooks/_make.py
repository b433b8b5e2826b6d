"""Build the example notebooks (``python notebooks/_make.py``; ``--execute`` also runs them and
saves their outputs, at the normal settings unless ``JAXCAL_NB_QUICK=1``).

Every notebook reads ``JAXCAL_NB_QUICK=1`` to shrink its settings (``tests/test_notebooks.py``
executes them that way). The sources live here so that all of them stay consistent.
"""

from __future__ import annotations

import pathlib
import sys

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

HERE = pathlib.Path(__file__).resolve().parent

def setup(stdlib=(), third=(), first=()) -> str:
    """The first code cell: imports (sorted as ruff's isort wants them: stdlib, third-party,
    jaxcal), the quick switch, float64, and ``show(fig)``."""
    std = sorted({"import io", "import os", *stdlib})
    third = sorted(third, key=lambda t: (t.startswith("from"), t.split()[1].lower()))
    first = ["import jaxcal", *sorted(first)]
    head = "\n\n".join("\n".join(block) for block in (std, third, first) if block)
    return head + """

QUICK = os.environ.get("JAXCAL_NB_QUICK", "0") == "1"  # small settings for the test suite
jaxcal.enable_x64()  # calibration wants float64 (jaxcal.enable_x64 says why)


def show(fig, width=960):
    \"\"\"Display a matplotlib Figure as a PNG about `width` pixels wide, never under 100 dpi
    (works with any backend, headless included).\"\"\"
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=max(100.0, width / fig.get_figwidth()))
    display(Image(buf.getvalue()))"""


def md(text: str):
    return new_markdown_cell(text.strip("\n"))


def code(text: str):
    return new_code_cell(text.strip("\n"))


# ---------------------------------------------------------------------------------------------------
def quickstart():
    return [
        md("""
# 01 · Quickstart: calibrate a simulated HSR-JR680 from draw-wire data

This notebook walks through one calibration of the paper's setting (Chen & Li, *AdaModW*):
a six-axis HSR-JR680 whose true DH parameters deviate from the nominal Table I by a few tenths
of a degree and millimetre, a draw-wire (cable-extension) sensor reading the distance from a
fixed anchor to the flange with Gaussian noise σ = 0.5 mm, 80 % of the samples for training
and 20 % held out.

* simulate the experiment (`jaxcal.simulate_experiment`),
* find which parameters the data can identify (`jaxcal.identifiability`),
* calibrate with Levenberg–Marquardt and with AdaModW (`jaxcal.calibrate`),
* compare with the statistical floor, read the calibrated DH table, save the result as JSON.
"""),
        code(setup(third=("import jax", "import numpy as np", "from IPython.display import Image, display"))),
        md("## Simulate the experiment"),
        code("""
N = 400 if QUICK else 2000
ex = jaxcal.simulate_experiment(jax.random.key(0), n_samples=N, noise_std=0.5)
print(f"{ex.train.n} training and {ex.test.n} test samples; wire lengths "
      f"{float(ex.train.y.min()):.0f}–{float(ex.train.y.max()):.0f} mm")
print("true deviations of joint 2: "
      f"Δα = {np.rad2deg(float(ex.true_deviations.alpha[1])):+.3f}°, Δa = {float(ex.true_deviations.a[1]):+.3f} mm")
"""),
        md("""
## Which parameters can distance data identify?

With one anchor and a wire attached at the flange centre, 19 of the 24 DH deviations are
identifiable: axes 2 and 3 are parallel (d2 and d3 only act as their sum), and several tool-end
parameters are invisible to a single distance. `calibrate` uses this identifiable subset by
default; the others stay at their nominal values.
"""),
        code("""
report = jaxcal.identifiability(ex.robot, ex.measurement, ex.train.q)
print(report)
"""),
        md("## Calibrate: Levenberg–Marquardt (M4) and AdaModW (M8)"),
        code("""
lm = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "lm")
adamodw = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "adamodw", key=jax.random.key(1),
                           steps=200 if QUICK else 500)
print(lm)
print(adamodw)
"""),
        code("""
from jaxcal import Problem

nominal = Problem(ex.robot, ex.measurement, ex.test.q, ex.test.y)
before = jaxcal.compute_metrics(nominal.sample_errors(nominal.x0()))
floor = jaxcal.statistical_floor(0.5, lm.space.n_free, ex.train.n)
rows = [["before calibration", *map(float, before)],
        ["LM", *lm.evaluate(ex.test)],
        ["AdaModW", *adamodw.evaluate(ex.test)],
        ["statistical floor (RMSE)", floor.test, None, None]]
print(jaxcal.format_table(rows, ["model", "RMSE/mm", "MEAN/mm", "MAX/mm"], title="Held-out accuracy"))
"""),
        md("""
The statistical floor σ√(1 + p/(n − p − 1)) is the expected RMSE on fresh poses of an exact
least-squares fit with a correct model and Gaussian noise: no method can do better on average
(one test split can land a little below it). The training curves show how the two get there:
LM in a handful of damped Gauss–Newton steps, AdaModW in a hundred or more gradient steps (its
β3 = 0.9 bound also acts as a ~10-step warm-up).
"""),
        code("""
from matplotlib.figure import Figure

fig = Figure(figsize=(6, 3.5), layout="constrained")
ax = fig.subplots()
for res, c in ((lm, "tab:purple"), (adamodw, "tab:red")):
    ax.plot(res.history[: res.n_iterations + 1], color=c, label=f"{res.method} ({res.n_iterations} iterations)")
ax.axhline(floor.train, color="k", ls="--", lw=1, label="floor (train)")
ax.set(xscale="symlog", yscale="log", xlabel="iteration", ylabel="training RMSE / mm", xlim=(0, None))
ax.xaxis.set_major_formatter("{x:g}")
ax.set_yticks([0.5, 1, 2, 5], ["0.5", "1", "2", "5"])
ax.yaxis.set_minor_formatter("")
ax.legend()
show(fig)
"""),
        md("## The calibrated DH table (the paper's Table V layout)"),
        code("""
nom, cal = ex.robot.dh_table_deg(), adamodw.dh_table()
true = nom + np.stack([np.rad2deg(np.asarray(ex.true_deviations.alpha)), np.asarray(ex.true_deviations.a),
                       np.asarray(ex.true_deviations.d), np.rad2deg(np.asarray(ex.true_deviations.theta))], 1)
rows = [[j + 1, *cal[j], *(cal[j] - true[j])] for j in range(6)]
print(jaxcal.format_table(rows, ["joint", "α/°", "a/mm", "d/mm", "θ/°", "Δα/°", "Δa/mm", "Δd/mm", "Δθ/°"],
                          title="AdaModW calibrated DH table and its error (calibrated − true)"))
print("not identifiable, kept nominal:", ", ".join(report.unidentifiable))
"""),
        md("""
Errors of identifiable parameters are tiny; the large-looking errors (e.g. d2 and d3) belong to
parameters that are only identifiable in combination, so they trade off against each other
without changing any predicted wire length.

## Save and load the result

`jaxcal.save_result` writes a JSON file (the same format as `jaxcal calibrate --out`);
`load_result` gives back a `CalibrationResult` that predicts and evaluates like the original.
"""),
        code("""
import tempfile

from jaxcal import load_result, save_result

path = os.path.join(tempfile.mkdtemp(), "lm.json")
save_result(lm, path, test_metrics_mm=lm.evaluate(ex.test))
back = load_result(path)
print(f"{os.path.getsize(path)} bytes; reloaded test RMSE {back.evaluate(ex.test).rmse:.6f} mm "
      f"(original {lm.evaluate(ex.test).rmse:.6f} mm)")
"""),
        md("""
From the command line the same steps are `jaxcal simulate --out data.csv`, then
`jaxcal calibrate data.csv --robot hsr_jr680 --method lm --out result.json`
(`jaxcal calibrate --help` describes the CSV layout).
"""),
    ]


# ---------------------------------------------------------------------------------------------------
def reproduce():
    return [
        md("""
# 02 · Reproduce the paper: Tables III–V and Figs. 2–4

The paper compares eight methods (Table II: M1 GA, M2 EKF, M3 BSO, M4 LM, M5 IWOA, M6 RBFNN,
M7 Adam, M8 AdaModW) on 2 000 draw-wire samples of one real robot. We repeat the comparison on
**simulated** experiments, one per seed: each seed draws a new true robot, new poses, new noise
and a new split, and every method sees the same data in that seed. Results are mean ± std over
seeds on the held-out 20 %, next to two references the paper lacks: the **statistical floor**
(the best any method can do with σ = 0.5 mm noise) and the **true model** evaluated on the same
test data.

`jaxcal reproduce` does the same from the command line (`--quick` for a smoke run).
"""),
        code(setup(third=("import numpy as np", "from IPython.display import Image, Markdown, display"),
                   first=("from jaxcal import PAPER_METHODS, plots, sweep",
                          "from jaxcal.methods import METHODS",
                          "from jaxcal.report import accuracy_table, convergence_table, dh_table"))),
        code("""
if QUICK:
    methods, n_seeds, n_samples = ["lm", "adamodw"], 3, 300
    hyper = {"adamodw": {"steps": 150}}
else:
    methods, n_seeds, n_samples = [m for m in PAPER_METHODS if m in METHODS], 8, 1000
    hyper = {}
missing = [m for m in PAPER_METHODS if m not in METHODS]
print("methods:", methods, "| not registered:", missing or "none")
res = sweep(methods, n_seeds, seed=0, n_samples=n_samples, noise_std=0.5, hyperparameters=hyper, progress=False)
res
"""),
        md("## Table III: accuracy on held-out data"),
        code("display(Markdown(accuracy_table(res, markdown=True)))"),
        md("""
Reading it: distance-only calibration of a correctly modelled robot on an identifiable
parameter set is a well-posed least-squares problem, so methods that run to convergence land
near the floor and the true model; the gaps below show how near. Remaining differences come
from budgets (population methods stop before the exact optimum), from the EKF's linearisation
per pass, and — for the RBF network — from fitting noise with extra degrees of freedom.
"""),
        code("""
best = min(res, key=lambda r: np.mean(r.test.rmse))
print(f"best mean test RMSE: {best.label} {np.mean(best.test.rmse):.4f} mm; "
      f"floor {res.floor.test:.4f} mm; true model {np.mean(res.oracle.rmse):.4f} mm")
for r in res:
    gap = np.mean(r.test.rmse) / np.mean(res.oracle.rmse) - 1
    print(f"  {r.label:8s} {100 * gap:+6.2f} % vs the true model")
"""),
        md("## Table IV: iterations and time"),
        code("display(Markdown(convergence_table(res, markdown=True)))"),
        md("""
Times are per trial inside one jitted function per chunk of trials (compilation excluded), so
they measure the algorithms' arithmetic, not Python overhead (on one CPU device the trials of a
chunk run one after the other, `jax.lax.map`; vmapped on GPUs, where a vmapped LM chunk lasts
until its slowest member converges). Iteration counts are not comparable across families: one LM iteration is a damped
Gauss–Newton step, one GA/BSO/IWOA iteration evaluates a whole population, one EKF iteration is
a pass over all samples.

## Table V: AdaModW's calibrated DH table (trial 0)
"""),
        code("display(Markdown(dh_table(res, markdown=True)))"),
        md("## Fig. 2: accuracy per method"),
        code("show(plots.fig2_accuracy(res))"),
        md("## Fig. 3: training curves and time"),
        code("show(plots.fig3_training(res))"),
        md("## Fig. 4: errors at 30 random test points"),
        code("show(plots.fig4_positioning(res))"),
    ]


# ---------------------------------------------------------------------------------------------------
def optax_chains():
    return [
        md("""
# 03 · AdaModW as an optax citizen: chains, clipping, schedules, `inject_hyperparams`

`jaxcal.optim.adamodw` is an `optax.GradientTransformation` (eqs. 6–15 of the paper), built from
the composable core `jaxcal.optim.scale_by_adamod`. So it chains with clipping and masks, takes
schedules, works under `optax.inject_hyperparams`, and any such chain can be handed to
`jaxcal.calibrate` as the method. The calibration parameters are the scaled deviations from the
nominal robot (a unit moves the RMS residual by ~1 mm), so one learning rate suits angles and
lengths, and weight decay pulls toward the nominal robot.
"""),
        code(setup(third=("import jax", "import jax.numpy as jnp", "import numpy as np", "import optax",
                          "from IPython.display import Image, display"))),
        code("""
N = 400 if QUICK else 2000
STEPS = 200 if QUICK else 500
ex = jaxcal.simulate_experiment(jax.random.key(3), n_samples=N)
space = jaxcal.identifiability(ex.robot, ex.measurement, ex.train.q).space
print(f"{ex.train.n} training samples, {space.n_free} identifiable parameters")
"""),
        md("""
## A user-made chain passed to `calibrate`

Gradient clipping, then AdaModW with a warm-up + cosine learning-rate schedule. With a schedule
the learning rate must live inside the transformation: η_t enters the moving average of step
sizes (eq. 11), so it cannot be a trailing `scale_by_learning_rate`.
"""),
        code("""
schedule = optax.warmup_cosine_decay_schedule(init_value=0.01, peak_value=0.2, warmup_steps=20,
                                              decay_steps=STEPS, end_value=0.005)
chain = optax.chain(
    optax.clip_by_global_norm(5.0),
    jaxcal.optim.adamodw(learning_rate=schedule, b3=0.9, weight_decay=1e-4),
)
chained = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, chain, steps=STEPS, space=space)
plain = jaxcal.calibrate(ex.robot, ex.measurement, ex.train, "adamodw", steps=STEPS, space=space)
for r in (plain, chained):
    m = r.evaluate(ex.test)
    print(f"{r.method:8s} test RMSE {m.rmse:.4f} mm, converged in {r.iterations_to_converge} iterations")
"""),
        md("""
## `optax.inject_hyperparams`: hyperparameters as state

Wrapped in `inject_hyperparams`, every numeric hyperparameter (η, β1–β3, ε, ξ) becomes an
array in the optimizer state: it can be changed between steps without recompiling, and vmapped
over (that is how `sweep(grid=...)` in notebook 04 runs a whole grid in one compilation).
Here we drive the optimizer by hand on the scaled problem and cut the learning rate tenfold
half-way through.
"""),
        code("""
from jaxcal import Problem
from jaxcal.methods import ScaledProblem

tx = optax.inject_hyperparams(jaxcal.optim.adamodw)(learning_rate=0.1, b3=0.9, weight_decay=1e-4)
sp = ScaledProblem.build(Problem(ex.robot, ex.measurement, ex.train.q, ex.train.y, space))


@jax.jit
def step(z, state):
    loss, grad = sp.loss_and_grad(z)
    updates, state = tx.update(grad, state, z)
    return optax.apply_updates(z, updates), state, jnp.sqrt(2 * loss)


z = jnp.zeros(sp.n_free)
state = tx.init(z)
manual = []
for t in range(STEPS):
    if t == STEPS // 2:
        state.hyperparams["learning_rate"] = jnp.asarray(0.01)  # no recompilation
    z, state, rmse = step(z, state)
    manual.append(float(rmse))
test = Problem(ex.robot, ex.measurement, ex.test.q, ex.test.y, space)
print(f"manual loop: final training RMSE {manual[-1]:.4f} mm, "
      f"test RMSE {float(jnp.sqrt(jnp.mean(test.sample_errors(sp.x(z)) ** 2))):.4f} mm")
"""),
        code("""
from matplotlib.figure import Figure

fig = Figure(figsize=(6.5, 3.6), layout="constrained")
ax = fig.subplots()
ax.plot(plain.history, label="adamodw (registry defaults)")
ax.plot(chained.history, label="clip + AdaModW + warm-up/cosine schedule")
ax.plot(np.arange(1, STEPS + 1) - 1, manual, label="inject_hyperparams, η ÷ 10 at half-way", ls="--")
floor = jaxcal.statistical_floor(0.5, space.n_free, ex.train.n).train
ax.axhline(floor, color="k", lw=1, ls=":", label="floor (train)")
ax.set(xscale="symlog", yscale="log", xlabel="iteration", ylabel="training RMSE / mm", xlim=(0, None))
ax.xaxis.set_major_formatter("{x:g}")
ax.set_yticks([0.5, 1, 2, 5], ["0.5", "1", "2", "5"])
ax.yaxis.set_minor_formatter("")
ax.legend(fontsize=8)
show(fig)
"""),
        md("""
All three reach the floor; the schedule trades a slower start for a smoother end. Other optax
pieces combine the same way: `optax.masked` (or AdaModW's own `mask=`) to decay only some
parameters, `optax.MultiSteps` for gradient accumulation over mini-batches
(`calibrate(..., batch_size=...)`), or a completely different optimizer such as
`optax.lbfgs()`... as long as the chain includes its own learning rate.
"""),
    ]


# ---------------------------------------------------------------------------------------------------
def seed_sweeps():
    return [
        md("""
# 04 · Seed sweeps: batched trials, a hyperparameter grid, several devices

One calibration says little: the spread over seeds (robots, poses, noise, splits) is as large
as the differences between good methods. `jaxcal.sweep` runs N seeded trials per method.
The data of a chunk of trials is simulated once (one jitted, vmapped function); then each
method calibrates and evaluates the whole chunk in **one** jitted function, so a sweep costs one
compilation per method. Inside it the trials are `jax.vmap`-ed (what fills a GPU, and what is
spread over several devices) or, on a single CPU device, run one after the other with
`jax.lax.map` (on 2 cores, from 4 seeds on, an LM chunk ran 1.2–1.9× as fast as a Python loop
over seeds and 1.4–7× as fast as a vmapped chunk, whose while-loop waits for its slowest trial;
AdaModW's fixed 500 steps ran within about ±20 % all three ways: `benchmarks/results/sweep_cpu.md`);
`batching="vmap" | "map" | "auto"` chooses.

Trial *i* uses `key_i = fold_in(key, i)`, split into a data key and a method key: every method
sees the same data in trial *i* (paired comparisons), and a trial's result does not depend on
how many trials the sweep has or how they are chunked.
"""),
        code(setup(stdlib=("import tempfile",), third=("import numpy as np", "from IPython.display import Image, Markdown, display"),
                   first=("from jaxcal import plots, sweep", "from jaxcal.report import grid_table"))),
        code("""
n_seeds = 3 if QUICK else 32
n_samples = 300 if QUICK else 2000
steps = 150 if QUICK else 500
grid = {"adamodw": {"b3": [0.9, 0.99, 0.999], "weight_decay": [0.0, 1e-4, 1e-2]}}
res = sweep(["lm"], n_seeds, seed=0, n_samples=n_samples, grid=grid,
            hyperparameters={"adamodw": {"steps": steps}}, progress=False)
print(res.labels)
"""),
        md("""
One call ran LM and a 3 × 3 grid of AdaModW's β3 × weight decay — the ablation the paper does
not report. Float-valued grid axes are traced (the hyperparameters are arrays, as under
`optax.inject_hyperparams`) and mapped over inside one compilation, so the nine settings cost
one compile, not nine.
"""),
        code("""
display(Markdown(grid_table(res, "adamodw", markdown=True)))
show(plots.grid_figure(res, "adamodw"))
"""),
        md("""
β3 sets the length of AdaModW's memory of step sizes; because b₀ = 0 the first steps are about
(1 − β3) of Adam's, an implicit warm-up of ~1/(1 − β3) steps, so a large β3 needs a larger step
budget. Weight decay shrinks toward the nominal robot: with identifiable, well-determined
parameters it can only add bias. The numbers:
"""),
        code("""
for b3 in grid["adamodw"]["b3"]:
    runs = [r for r in res if r.grid_point and r.grid_point["b3"] == b3]
    its = np.mean([np.mean(r.iterations_to_converge) for r in runs])
    rmse = {r.grid_point["weight_decay"]: np.mean(r.test.rmse) for r in runs}
    print(f"b3 = {b3}: ~{its:.0f} iterations to converge (of {steps}); test RMSE by weight decay "
          + ", ".join(f"{wd:g}: {v:.4f}" for wd, v in rmse.items()))
print(f"LM: {np.mean(res['lm'].test.rmse):.4f} mm; statistical floor {res.floor.test:.4f} mm")
"""),
        md("## Paired comparison over seeds"),
        code("""
ad = res["adamodw[b3=0.9, weight_decay=0.0001]"]  # the registry default
diff = ad.test.rmse - res["lm"].test.rmse
print(f"AdaModW − LM test RMSE per seed: mean {diff.mean() * 1e3:+.2f} µm, std {diff.std(ddof=1) * 1e3:.2f} µm; "
      f"spread of LM's test RMSE over seeds: std {res['lm'].test.rmse.std(ddof=1) * 1e3:.1f} µm")
print(f"AdaModW better in {int((diff < 0).sum())} of {n_seeds} seeds")
"""),
        md("""
Compare the paired difference with the spread of a single method over seeds: when two methods
both reach the floor, the seed-to-seed spread is far larger than their difference, so a single
run (as in the paper's tables) cannot rank them; paired differences over many seeds can.

## Resumable sweeps: `out_dir`

With `out_dir`, every finished chunk is written at once (`chunks/<run>/trials_a-b.npz`); a rerun
with the same settings loads the finished chunks and computes only the missing ones, and
`jaxcal.load_sweep` rebuilds the result from the directory.
"""),
        code("""
from jaxcal import load_sweep

out = tempfile.mkdtemp()
first = sweep(["lm"], n_seeds, seed=0, n_samples=n_samples, out_dir=out, progress=False)
again = sweep(["lm"], n_seeds, seed=0, n_samples=n_samples, out_dir=out)  # progress shows "loaded"
assert np.array_equal(first["lm"].x, again["lm"].x)
print(sorted(os.listdir(os.path.join(out, "chunks"))), load_sweep(out))
"""),
        md("""
## Several devices

`sweep(..., devices=jax.devices())` (the default) spreads each chunk over all devices: the keys
of the chunk's trials are sharded along a one-axis mesh `Mesh(devices, ("trials",))` with
`NamedSharding(mesh, P("trials"))`, everything else is replicated, and XLA partitions the
vmapped trial along that axis. Each device computes its own batch of `chunk_size` trials, with
bitwise the same results as one device computing that batch with `batching="vmap"`.

Why not `jax.shard_map`? Inside `shard_map` (and `pmap`, which is built on it in JAX 0.10)
every traced value carries a manual-axis sharding in its type, and lineax compares a vector's
`ShapeDtypeStruct` (with that sharding) to an operator's (without): optimistix's LM fails with
*"Vector and operator structures do not match"* (lineax#185 upstream). Sharded inputs under plain
`jit` avoid it.

On a multi-GPU machine nothing changes; on several hosts call `jax.distributed.initialize()`
first in every process and run the same script: the mesh spans all hosts' devices, process 0
writes `out_dir`. To try it on CPU, force several host devices *before* importing JAX:
"""),
        code("""
import subprocess
import sys
import textwrap

script = textwrap.dedent('''
    import os
    os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=4"
    import jax, numpy as np
    jax.config.update("jax_enable_x64", True)
    from jaxcal import sweep
    kw = dict(seed=1, n_samples=300, chunk_size=2, progress=False)
    four = sweep(["lm"], 8, devices=4, **kw)
    one = sweep(["lm"], 8, devices=1, batching="vmap", **kw)
    print(len(jax.devices()), "devices; identical to one device:", np.array_equal(four["lm"].x, one["lm"].x))
''')
if QUICK:
    print("(skipped in quick mode: the subprocess compiles everything again)")
else:
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    print(done.stdout or done.stderr[-2000:])
"""),
    ]


# ---------------------------------------------------------------------------------------------------
def real_data():
    return [
        md("""
# 05 · Real, messy data: initialise, diagnose, regularise, validate by region, read the σ

Simulated data that matches the model is easy: every method reaches the statistical floor. Real
draw-wire sessions are not like that: the anchor is guessed hundreds of mm off,
the wrist joints move only 10–20°, joint readings are quantised, joints bend under gravity, and
a wire slips now and then. `jaxcal.simulate_messy` simulates exactly that, from a seed, so we can
check every step against the truth.

1. **initialise** the sensor's unknowns from the data (`extras=`, closed-form multilateration),
2. **diagnose**: an unregularised fit looks fine on held-out data from the measured region and
   is absurd everywhere else — jaxcal says so (`result.warnings`, `result.plausible`),
3. **regularise** with priors toward the nominal robot (`prior=`), strength by cross-validation
   with workspace-region folds (`jaxcal.cross_validate_prior`),
4. **outliers**: named by row; a robust loss (`loss="huber"`) makes them harmless,
5. **read the uncertainties** (`result.uncertainty`, `result.prediction_std`).
"""),
        code(setup(stdlib=("import warnings",), third=("import jax", "import matplotlib.pyplot as plt",
                                                     "import numpy as np", "from IPython.display import Image"))),
        code("""
ex = jaxcal.simulate_messy(jax.random.key(0), n_samples=400 if QUICK else 1000)
print(ex.describe())
robot, measurement = ex.robot, ex.measurement  # the measurement holds the (wrong) anchor guess
"""),
        md("""
## 1 · Start the anchor and cable offset from the data

The guessed anchor is 500 mm off: the nominal robot's RMS residual is hundreds of mm. With
`extras=("anchor", "cable_offset")` jaxcal estimates them with the robot, and (by default,
`init="auto"`) first solves for them in closed form on the nominal robot.
"""),
        code("""
est = jaxcal.initial_extras(robot, measurement, ex.train)
print(est.message)
print("true anchor deviation from the guess:", np.round(np.asarray(ex.true_deviations.anchor), 1), "mm")
"""),
        md("""
## 2 · Without a prior: a good fit with absurd parameters

Least squares on the identifiable subset fits the measured region well. The diagnostics say what
is wrong: a step budget exhausted, DH deviations of tens of mm and degrees, two joints that
barely moved. The `far` test set — poses over the whole joint limits, where nobody measured —
shows what such a model is worth.
"""),
        code("""
extras = ("anchor", "cable_offset")
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    plain = jaxcal.calibrate(robot, measurement, ex.train, "lm", extras=extras)
    mapfit = jaxcal.calibrate(robot, measurement, ex.train, "lm", extras=extras, prior="default")
for name, res in [("no prior", plain), ("default prior", mapfit)]:
    print(f"{name:14s} status {res.status.name:9s} plausible {res.plausible!s:5s} "
          f"test {res.evaluate(ex.test).rmse:.3f} mm   far {res.evaluate(ex.far).rmse:.2f} mm")
print()
print("\\n".join("* " + w for w in plain.warnings))
"""),
        md("""
## 3 · Prior strength by cross-validation, including workspace-region folds

`cross_validate_prior` refits with priors of several strengths (strength *s* divides the default
σ = 0.5°, 2 mm) on 5 random folds (interpolation) and on 6 workspace-region folds (train where
q1, q2 or q3 is below its median, test above, and the reverse: extrapolation).
"""),
        code("""
strengths = (0.0, 1.0, 4.0) if QUICK else (0.0, 0.25, 1.0, 4.0, 16.0)
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    cv = jaxcal.cross_validate_prior(robot, measurement, ex.train, strengths=strengths, extras=extras)
print(cv.table())
ax = cv.plot()
ax.figure.tight_layout()
show(ax.figure)
plt.close(ax.figure)
"""),
        md("""
In the run shown the chosen strength, 16, is the strongest on the grid, so the best value may
lie beyond it: the table cannot show where the held-out RMSE turns up again. Before relying on the choice, extend the grid (for example
`strengths=(4.0, 16.0, 64.0, 256.0)`) and check that the chosen strength is then inside it. A
strength far beyond the grid pins the deviations at nominal, which the training RMSE shows as it
rises.
"""),
        md("""
## 4 · Outliers: named, and harmless with a robust loss

Nothing is dropped silently: the rows whose residual exceeds 5 robust σ are listed (here they are
the two rows the simulator corrupted). Excluding them is your choice; the Huber loss makes the fit
insensitive to them without a decision.
"""),
        code("""
print("planted outliers:", ex.outlier_rows, "  flagged:", mapfit.diagnostics.outliers_after)
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    robust = jaxcal.calibrate(robot, measurement, ex.train, "lm", extras=extras, prior=cv.prior(), loss="huber")
print(f"CV prior + Huber: test {robust.evaluate(ex.test).rmse:.3f} mm, far {robust.evaluate(ex.far).rmse:.2f} mm, "
      f"loss scale {robust.loss_scale_mm:.2f} mm")
"""),
        md("""
## 5 · Uncertainties

`result.uncertainty.std` is the posterior σ of every free parameter (prior and data combined,
residual σ estimated from the fit). Under the prior every DH deviation is free (maximum a
posteriori), so a single parameter is partly set by the prior; what the data determine are
combinations, such as the reading at a pose. `result.prediction_std(q)` is the σ of the
predicted reading at new poses: small where we measured, large far away — a map of where this
calibration can be trusted. With noise alone the true robot's readings would lie within about
±3 of it; this simulated robot also has unmodelled compliance and gear errors, which no posterior
σ covers, so the ratio printed below comes out larger (8.1 at the full setting) — posterior σ
describe the noise, not a model error.
"""),
        code("""
truth = np.asarray(ex.measurement.predict(ex.robot, ex.true_deviations, ex.test.q))
z = (np.asarray(robust.predict(ex.test.q)) - truth) / np.asarray(robust.prediction_std(ex.test.q))
print("held-out poses: largest |predicted − true reading| / predicted σ:", f"{np.max(np.abs(z)):.2f}")
for name, (s, unit) in list(robust.uncertainty.std_display().items())[:6]:
    print(f"  σ({name}) = {s:.3g} {unit}")
print(f"predicted reading σ: measured region {np.median(robust.prediction_std(ex.test.q)):.3f} mm, "
      f"whole workspace {np.median(robust.prediction_std(ex.far.q)):.3f} mm (median)")
"""),
        md("""
The command line does all of this by default (`jaxcal calibrate DATA.csv --robot ... --estimate
anchor,offset`: prior on, extras initialised, warnings printed, exit status 1 for an implausible or
unfinished calibration). `benchmarks/bench_real_data.py` measures the trade-off over several seeds
and methods (results in `benchmarks/results/real_data_cpu.md`).
"""),
    ]


# ---------------------------------------------------------------------------------------------------
def plan_measurements():
    return [
        md("""
# 06 · Plan the measurements: which poses, how many, and how accurate?

Measuring is the expensive part of a calibration: every pose costs a robot move and a sensor
reading. Before touching the robot, jaxcal answers three questions for the paper's HSR-JR680
draw-wire set-up (σ = 0.5 mm):

1. **how good is a pose set?** — observability indices O1–O5 of the column-scaled identification
   Jacobian (`jaxcal.observability_indices`);
2. **which poses?** — greedy D-optimal selection from candidates inside the joint limits and the
   wire's range, refined by a DETMAX exchange (`jaxcal.select_poses`), compared with random poses
   and with the convex relaxation FIGAROH uses (`jaxcal.relaxed_design`);
3. **how accurate, with how many?** — the predicted test RMSE and per-parameter σ from the
   linearised covariance σ²(JᵀJ)⁻¹ (`jaxcal.predicted_accuracy`), the curve against the number of
   poses (`jaxcal.accuracy_curve`), and a check against simulated calibrations.
"""),
        code(setup(stdlib=("import warnings",), third=("import jax", "import numpy as np",
                                                     "from IPython.display import Image, display"),
                   first=("from jaxcal._experiments import _plan", "from jaxcal._simulation._simulate import default_anchor"))),
        md("## Candidates: random poses inside the joint limits and the wire's length window"),
        code("""
robot = jaxcal.robots.hsr_jr680()
meas = jaxcal.CableLength(default_anchor(robot))
N_CAND = 2000 if QUICK else 20000
cand = jaxcal.candidate_poses(jax.random.key(0), robot, meas, N_CAND)
q_test = jaxcal.candidate_poses(jax.random.key(1), robot, meas, 1000 if QUICK else 2000)  # "the workspace"
print(cand.shape, "candidates;", q_test.shape[0], "test poses")
"""),
        md("""
## Select poses and read the indices

`select_poses` computes the Jacobians of all candidates at once, keeps the identifiable
parameters (19 of the 24 DH deviations for one draw wire), and adds, one at a time, the candidate
that increases log det(JᵀJ) most (rank-one updates, every candidate scored at once); the DETMAX
exchange then swaps poses while the determinant grows. O1 is the D-optimality index (≤ 1 with
jaxcal's column scaling), O3 the smallest singular value (0 for a set that cannot identify
everything).
"""),
        code("""
N = 40 if QUICK else 100
sel = jaxcal.select_poses(robot, meas, cand, N)
print(sel.table())
rand = np.asarray(cand)[:N]  # the candidates are random already
print("random:", _plan.indices_from_jacobian(_plan.planning_jacobian(robot, meas, rand, sel.space), sel.scale))
"""),
        md("## Predicted accuracy, before measuring"),
        code("""
p_sel = jaxcal.predicted_accuracy(robot, meas, sel.q, 0.5, q_test=q_test)
p_rnd = jaxcal.predicted_accuracy(robot, meas, rand, 0.5, q_test=q_test)
print(f"predicted test RMSE: selected {p_sel.test_rmse:.4f} mm, random {p_rnd.test_rmse:.4f} mm")
print(p_sel.table())
"""),
        md("""
## Check the prediction: simulated calibrations at the planned poses

Per seed: a "true" robot drawn with the paper's Table V magnitudes, noisy readings at the planned
poses and at the test poses, `calibrate(..., "lm")`. The mean test RMSE over the seeds should
match the prediction within a few per cent.
"""),
        code("""
def simulated(q, seeds):
    out = []
    for seed in range(seeds):
        k1, k2 = jax.random.split(jax.random.key(100 + seed))
        train, truth = _plan.simulate_readings(k1, robot, meas, q, 0.5)
        test, _ = _plan.simulate_readings(k2, robot, meas, q_test, 0.5, true_deviations=truth)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out.append(jaxcal.calibrate(robot, meas, train, "lm").evaluate(test).rmse)
    return np.mean(out)


SEEDS = 5 if QUICK else 20
for name, q, p in [("selected", sel.q, p_sel), ("random", rand, p_rnd)]:
    m = simulated(q, SEEDS)
    print(f"{name:9s} predicted {p.test_rmse:.4f} mm, simulated mean over {SEEDS} seeds {m:.4f} mm "
          f"({100 * (m / p.test_rmse - 1):+.1f} %)")
"""),
        md("""
## How many poses? Predicted test RMSE vs number of poses

Greedy prefixes vs random prefixes of the same candidates. The noise floor σ is the asymptote;
the target line is 5 % above the predicted RMSE of 2 000 random poses.
"""),
        code("""
ns = [25, 30, 40, 60, 100, 150, 200, 300, 500] + ([] if QUICK else [1000, 2000])
curve = jaxcal.accuracy_curve(robot, meas, cand, ns, 0.5, q_test=q_test)
target = 1.05 * jaxcal.predicted_accuracy(robot, meas, np.asarray(cand)[-2000:], 0.5, q_test=q_test).test_rmse
print(f"target {target:.4f} mm; D-optimal poses needed (greedy prefixes, on this grid): {curve.poses_needed(target)}")
show(curve.plot(target_rmse=target))
"""),
        md("""
## The convex relaxation (FIGAROH's approach), solved by multiplicative weights

Relax "pick n poses" to weights on the candidates and maximise log det Σ w_k J_kᵀJ_k (concave);
FIGAROH solves it as an SOCP, jaxcal with the classical multiplicative algorithm, then keeps the
n largest weights. On this set-up it is no better than the greedy selection (see
`benchmarks/results/plan_cpu.md`).
"""),
        code("""
rel, w, bound = jaxcal.relaxed_design(robot, meas, cand, N, iters=200 if QUICK else 500)
p_rel = jaxcal.predicted_accuracy(robot, meas, rel.q, 0.5, q_test=q_test)
print(f"D-efficiency bound of the weights {bound:.4f}; top-{N} rounding: O1 {rel.indices.o1:.4f} "
      f"(greedy+exchange {sel.indices.o1:.4f}), predicted test RMSE {p_rel.test_rmse:.4f} mm")
"""),
        md("""
## From the command line

`jaxcal plan --robot hsr_jr680 --measurement cable --poses 100 --out poses.csv --plot curve.png`
writes the poses as a data file with an empty `length_mm` column: fill in the readings, then
`jaxcal calibrate poses.csv --robot hsr_jr680`.
"""),
    ]


# ---------------------------------------------------------------------------------------------------
def low_cost():
    return [
        md("""
# 07 · Calibrate without a tracker: a probe touching three planes

No laser tracker, no motion capture: a touch probe (or a dial indicator zeroed on contact) on the
tool, and three flat surfaces — a table and two walls or the faces of a machined block. Each
contact gives one number, the signed distance of the tool tip to the plane it touched, which the
calibrated robot should make zero. Neither the planes nor the probe tip are known: both start from
the data in closed form (an SVD plane fit per plane, the tip by linear least squares) and are
then calibrated with the robot (`jaxcal.PlaneContact`, README "Without a tracker").
"""),
        code(setup(stdlib=("import tempfile", "import warnings"),
                   third=("import jax", "import matplotlib.pyplot as plt", "import numpy as np",
                          "from IPython.display import Image, display"),
                   first=("from jaxcal._sensors._contact import default_setup, unobservable_directions",))),
        md("""
## Simulated probing

A "true" HSR-JR680 (the paper's Table V magnitudes of DH errors, a probe tip 2 mm off its nominal
position); random poses moved onto the planes by minimum-norm Newton steps on the true robot, the
contact noise σ = 0.05 mm along each plane's normal. The file has one text column, `plane`.
"""),
        code("""
robot = jaxcal.robots.hsr_jr680()
setup_ = default_setup("plane", robot)  # a table tilted 5°, two walls 60° apart
N = 150 if QUICK else 300
SIGMA = 0.05
ex = jaxcal.simulate_contact(jax.random.key(0), robot, setup_, n_samples=N, noise_std=SIGMA, test_fraction=0.0)
fresh = jaxcal.simulate_contact(jax.random.key(1), robot, setup_, n_samples=1000 if QUICK else 3000,
                                noise_std=SIGMA, true_deviations=ex.true_deviations, test_fraction=0.0).train
path = os.path.join(tempfile.mkdtemp(), "probing.csv")
ex.train.to_csv(path)
print("".join(open(path).readlines()[:10]))
data = jaxcal.load_csv(path)
print(data.kind, data.n, "rows; planes:", data.meta["plane_labels"])
"""),
        md("""
## The closed-form start

`calibrate` calls `jaxcal.initial_extras`, which for plane data fits each plane to the nominal
robot's tool points and then solves for the probe tip and the offsets with the normals fixed. The
model's nominal planes are all `z = 0`: the start turns them into walls where the data say so.
"""),
        code("""
model = jaxcal.PlaneContact.from_dataset(data)  # labels only: normals (0, 0, 1), offsets 0
start = jaxcal.initial_extras(robot, model, data, estimate=("plane", "tool"))
print(start.message)
n_fit, d_fit = model.planes(start.deviations)
for k, name in enumerate(model.labels):
    tilt = np.degrees(np.arccos(np.clip(np.asarray(n_fit[k]) @ np.asarray(setup_.normals[k]), -1, 1)))
    print(f"{name:7s} normal off by {tilt:.3f}°, offset off by {float(d_fit[k] - setup_.offsets[k]):+.3f} mm")
"""),
        md("""
## What planes can see

With one plane the robot can slide along it and turn about its normal without changing a single
contact: the identifiability report shows it as θ₁ without effect and d₁ acting like the plane's
offset. Three planes with independent normals see every rigid motion. (The planes are in the
robot's base frame, so they absorb any base-frame error; that is why there is no `base` extra.)
"""),
        code("""
print("one plane:   ", unobservable_directions(np.asarray(setup_.normals[:1])))
print("two planes:  ", unobservable_directions(np.asarray(setup_.normals[:2])))
print("three planes:", unobservable_directions(np.asarray(setup_.normals)))
space = jaxcal.ParameterSpace.for_robot(robot, measurement=model, tool=True)
rep = jaxcal.identifiability(robot, model, data.q, space, start.deviations)
print(f"three planes: rank {rep.rank} of {len(rep.names)}; not identifiable: {', '.join(rep.unidentifiable)}")
"""),
        md("""
## Calibrate, and compare with the statistical floor

The measured-data defaults: a prior toward the nominal robot and the Huber loss. The prior matters
more here than elsewhere: **contact data carry no length reference** — scaling every length of the
robot, the tip and the planes' offsets by the same factor keeps every contact — and since the
residuals shrink with the scale, plain least squares walks toward a robot of size zero. The
prior's 2 mm on each DH length holds the scale (so would fixing one length, `fix="a_2"`).
"""),
        code("""
with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    res = jaxcal.calibrate(robot, model, data, "lm", extras=["tool"], objective="measured")
    plain = jaxcal.calibrate(robot, model, data, "lm", extras=["tool"])  # no prior, no length reference
floor = jaxcal.statistical_floor(SIGMA, res.identifiability.rank, data.n, 1)
test = res.evaluate(fresh).rmse
print(f"with the prior: train {res.train_metrics.rmse:.4f} mm, fresh poses {test:.4f} mm, floor {floor.test:.4f} mm "
      f"(ratio {test / floor.test:.3f})")
print(f"plain least squares: train {plain.train_metrics.rmse:.2e} mm, Δa_2 = {float(plain.deviations.a[1]):+.0f} mm "
      f"— the robot shrank")
tip = np.asarray(res.deviations.tool) - np.asarray(ex.true_deviations.tool)
print("probe tip error (mm):", np.round(tip, 3))
"""),
        code("""
before = np.asarray(model.residual(robot, start.deviations, fresh.q, fresh.y))[:, 0]
after = np.asarray(model.residual(robot, res.deviations, fresh.q, fresh.y))[:, 0]
lab = np.asarray(fresh.y).astype(int)
fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
for k, name in enumerate(model.labels):
    ax[0].hist(before[lab == k], bins=40, alpha=0.6, label=name)
ax[0].set(title="fresh contacts, nominal robot + closed-form planes", xlabel="signed distance / mm")
ax[0].legend()
ax[1].hist(after, bins=40, color="C2")
ax[1].axvline(-floor.test, color="k", ls="--", label="± floor (RMS)")
ax[1].axvline(floor.test, color="k", ls="--")
ax[1].set(title=f"after calibration (RMSE {test:.3f} mm)", xlabel="signed distance / mm")
ax[1].legend()
fig.tight_layout()
show(fig)
plt.close(fig)
"""),
        md("""
The same from the command line: `jaxcal simulate --measurement plane --out probing.csv`, then
`jaxcal calibrate probing.csv --robot hsr_jr680 --measurement plane --out result.json` (the planes
and the tip are estimated by default). `--measurement point` (pivoting on fixed points) and
`--measurement distance` (a bar or ballbar; it never sees the base frame, but it does see the
scale) work the same way.
"""),
    ]


# ---------------------------------------------------------------------------------------------------
def combined():
    return [
        md("""
# 08 · A known length: ball-in-socket data that see the robot's scale

A cheap calibration set-up: a ball on the flange, a plate with two conical sockets machined a
known 50.00 mm apart, and the robot driven so that the ball sits in one socket or the other in
many orientations. Each row is the joint angles and the name of the socket. The sockets' positions
are unknown; the rows only say "the ball centre was at the same point as in that socket's other
rows". Such data pin down the robot's angles and the ball's offset, but not its **length
scale**: make every length of the robot, the ball offset and the plate larger by the same
factor, and every row still holds.

The known distance between the sockets is what fixes the scale. `jaxcal.calibrate_blocks` takes
the data as one or more blocks plus a list of **known relations** (`jaxcal.KnownDistance`), and
it reports which block determines what. This notebook:

* simulates a robot whose links are 1.5 % longer than nominal, probed at six plate placements;
* calibrates with and without the known distances;
* evaluates both results on two held-out placements (`jaxcal.evaluate_result` registers their new
  sockets with the robot fixed) and compares the held-out socket distance with 50.00 mm;
* shows the report that says the scale is set by the relations.
"""),
        code(setup(stdlib=("import tempfile", "import warnings"),
                   third=("import jax", "import matplotlib.pyplot as plt", "import numpy as np",
                          "from IPython.display import Image, display"),
                   first=("from jaxcal import Block, FixedPoint, KnownDistance",))),
        md("""
## Simulated ball-in-socket data

Six placements of the plate near the middle of the workspace, each turned about the vertical.
Four are for calibration (sockets `a0 b0 … a3 b3`), two are held out (`a4 b4 a5 b5`). The true
robot has every link length (DH `a` and `d`) 1.5 % longer than nominal and the ball 80 mm off the
flange; the noise is σ = 0.02 mm per axis. `simulate_contact` moves random poses onto the sockets
with the true robot.
"""),
        code("""
robot = jaxcal.robots.hsr_jr680()
SOCKETS_MM, SIGMA = 50.0, 0.02
rng = np.random.default_rng(7)


MIDDLE = np.array([15.0, 15.0, 1150.0])  # mm, in the robot's base frame


def plate():
    \"\"\"Two socket centres 50 mm apart, the plate somewhere near MIDDLE and turned.\"\"\"
    c = MIDDLE + rng.uniform(-150, 150, 3) * [1, 1, 0.5]
    t = rng.uniform(0, np.pi)
    u = np.array([np.cos(t), np.sin(t), rng.uniform(-0.1, 0.1)])
    u *= SOCKETS_MM / 2 / np.linalg.norm(u)
    return [c - u, c + u]


centres = np.array([p for _ in range(6) for p in plate()])
labels = [f"{s}{k}" for k in range(6) for s in "ab"]


def truth_for(model):  # 1.5 % longer links and the ball 80 mm off the flange
    layout = jaxcal.ParameterSpace.for_robot(robot, measurement=model).layout
    return jaxcal.Deviations.zeros(layout).replace(
        a=0.015 * np.asarray(robot.a), d=0.015 * np.asarray(robot.d), tool=np.array([3.0, -2.0, 80.0]))


n_train, n_test = (240, 120) if QUICK else (320, 160)
train_model, test_model = FixedPoint(labels[:8], centres[:8]), FixedPoint(labels[8:], centres[8:])
train = jaxcal.simulate_contact(jax.random.key(11), robot, train_model, n_samples=n_train, noise_std=SIGMA,
                                test_fraction=0.0, true_deviations=truth_for(train_model)).train
held_out = jaxcal.simulate_contact(jax.random.key(12), robot, test_model, n_samples=n_test, noise_std=SIGMA,
                                   test_fraction=0.0, true_deviations=truth_for(test_model)).train
path = os.path.join(tempfile.mkdtemp(), "sockets.csv")
train.to_csv(path)  # the file a user has: joint angles (deg) and a `point` label column
print("".join(open(path).readlines()[:6]))
data = jaxcal.load_csv(path)
print(data.kind, data.n, "rows; sockets:", data.meta["point_labels"])
"""),
        md("""
## Calibrate with and without the known distances

One block, `sockets`: a `FixedPoint` model with the socket names only (their centres start from
the data in closed form) and the tool (the ball's centre) estimated. The relations are one
`KnownDistance` per placement, with the machining tolerance as its σ. The measured-data defaults
(`objective="measured"`: a Huber loss and a prior toward the nominal robot) are what the CLI uses
on real files; without the relations, that prior is the only thing that holds the scale.
"""),
        code("""
relations = [KnownDistance(f"a{k}", f"b{k}", SOCKETS_MM, std_mm=0.005) for k in range(4)]
fits, evaluations = {}, {}
for name, rel in (("with the known distances", relations), ("without", [])):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fits[name] = jaxcal.calibrate_blocks(robot, [Block("sockets", FixedPoint.from_dataset(data), data,
                                                           extras="tool")], rel, objective="measured")
    # the held-out placements: their sockets are new labels, registered with the calibrated robot fixed
    evaluations[name] = jaxcal.evaluate_result(jaxcal.block_result(fits[name], "sockets"), held_out)
    print(name)
    for stats in fits[name].blocks:
        print("  ", stats.line())

errors = {}
for name, ev in evaluations.items():
    v = ev.deviations_after.values
    errors[name] = [float(np.linalg.norm(np.asarray(v[f"point@b{k}"]) - np.asarray(v[f"point@a{k}"])) - SOCKETS_MM)
                    for k in (4, 5)]
    print(f"{name:>26}: held-out socket distance − 50 mm = "
          + ", ".join(f"{e:+.3f}" for e in errors[name]) + " mm; "
          + f"held-out RMSE {ev.after.rmse:.4f} mm (expected {ev.expected_rmse:.4f} mm)")
"""),
        md("""
Both fits reach the noise on the held-out rows: consistency alone cannot tell them apart. Only
the known length can: without it the held-out sockets come out about 0.83 mm (1.7 %) too close,
because the prior keeps the nominal (too short) link lengths, and the ball offset and socket
positions shrink with them. With the four known distances the error is below 0.01 mm.
"""),
        code("""
fig, ax = plt.subplots(figsize=(7, 3.2))
names = list(errors)
for i, name in enumerate(names):
    ax.bar(np.arange(2) + 0.38 * i, np.abs(errors[name]), width=0.36, label=name)
ax.set_xticks(np.arange(2) + 0.19, ["placement 4", "placement 5"])
ax.set_yscale("log")
ax.set_ylim(1e-3, 30)  # room above the bars for the legend
ax.set_ylabel("|socket distance error| (mm)")
ax.legend(loc="upper left")
ax.set_title("held-out socket distance against the machined 50.00 mm")
fig.tight_layout()
show(fig)
plt.close(fig)
"""),
        md("""
## Which block sees what

`CombinedResult.block_report` compares each block's information with the total. For these data it
names the direction that only the relations see: a combination of the link lengths (`a`, `d`),
the length scale. Without the relations that direction is not identifiable.
"""),
        code("""
for line in fits["with the known distances"].block_report:
    if "relations" in line:
        print(line)
"""),
        md("""
## The same from the command line

Write the relations in a small text file (one per line: `distance <a> <b> <mm> <σ mm>`), give
the data files with `--combine`, and evaluate the held-out file; its new socket labels are
registered by name:

```bash
jaxcal calibrate sockets.csv --robot hsr_jr680 --combine --relations rel.txt --estimate tool --out-dir fit
jaxcal evaluate fit/sockets.json held_out.csv
```

`--combine` also takes several files of different sensors (a tracker file and a camera file, plane
contacts and a distance bar): each file is one block with its own noise σ, estimated from the
data, and the report says which block determines what.
"""),
    ]

NOTEBOOKS = {
    "01_quickstart.ipynb": quickstart,
    "02_reproduce_paper.ipynb": reproduce,
    "03_optax_chains.ipynb": optax_chains,
    "04_seed_sweeps.ipynb": seed_sweeps,
    "05_real_data.ipynb": real_data,
    "06_plan_measurements.ipynb": plan_measurements,
    "07_low_cost_calibration.ipynb": low_cost,
    "08_known_length.ipynb": combined,
}


def build(name: str) -> nbformat.NotebookNode:
    nb = new_notebook(cells=NOTEBOOKS[name]())
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    nb.metadata["language_info"] = {"name": "python"}
    return nb


def main(argv: list[str]) -> None:
    execute = "--execute" in argv
    names = [a for a in argv if a.endswith(".ipynb")] or list(NOTEBOOKS)
    for name in names:
        nb = build(name)
        if execute:
            from nbclient import NotebookClient

            NotebookClient(nb, timeout=3600, kernel_name="python3", resources={"metadata": {"path": str(HERE)}}).execute()
        nbformat.write(nb, HERE / name)
        print("wrote", HERE / name)


if __name__ == "__main__":
    main(sys.argv[1:])
