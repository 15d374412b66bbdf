"""A refactor against the code before it: every output the same, bit for bit.

    python experiments/refactor/same_bits.py --old REV [--cases components,fit,check,cli]

The old tree is checked out with ``git worktree`` (removed afterwards); each case runs in a child process whose
``sys.path`` starts with one tree and prints a digest: the SHA-256 of every number it computed, written with
``float.hex`` (so equal digests mean equal bits), and a few of the numbers for the eye. Cases:

* ``components`` — every built-in effect in a model (``fractional+white+EFFECT``, its inputs a warm-up temperature):
  its spectrum at 64 frequencies, its mean, 2000 simulated samples (seeded), the exact log-likelihood there;
* ``fit`` — the exact fit (values, standard errors, intervals, log-likelihoods) of fractional+white+random-walk to
  6000 simulated samples;
* ``check`` — ``check`` of 6000 samples with a hidden sinusoid and temperature bias, every candidate screened:
  the screens' rows (statistics, p-values, notes), the suggestions (gains, parameters), the diagnostics;
* ``loop`` — ``check(...).auto()`` of 6000 samples with a temperature-driven order, a step and three spikes: every
  step's document (its screens — the spikes' count chosen by their screen, the temperature-order scan past its first
  stage — suggestions, diagnostics and fit);
* ``starts`` — every built-in effect's starts in ``fractional+white+EFFECT`` on 2000 simulated samples: the data's
  starting values, the least-squares start of the mean (values and residual), the refit strengths and the vanishing
  values against fractional+white, the Whittle fit from the grid (where stationary), a located parameter's interval;
* ``tea`` — the TEA's engines: the torch engine (exact and soe memory), the compiled one, the kernel's other branches
  (window memory, the paper's gain, constant truth, KFo's R from the innovations) on both, the paper's example 1 with
  its known input, a ``TEAStream`` step by step — every returned array;
* ``tea_exact`` — the TEA with the exact filter as KFx (``run_tea_exact``) on a grown model's three series with a
  missing sample: KFo and KFw apart and joint, one view per series, numeric R;
* ``cli`` — ``torchtea fit --json`` of the bundled recording's first 3000 samples (the seconds, the command and
  the file's path — each tree's own — left out);
* ``export`` — ``torchtea export --format all`` of two simulated channels (6000 samples, fractional+white+random-walk,
  an 8-realisation filter study): every file it writes, as text (the run's folder, the command, the recording's path
  and ``export.json``'s ``topic``, which later code adds, left out).

Writes experiments/refactor/same_bits.json.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]

CHILD = r'''
import hashlib, json, math, sys
import numpy as np
import torch
torch.set_num_threads(1)
case = sys.argv[1]
H = 0.01

def flat(x, out):
    """Every number in x (nested dicts, lists, arrays, tensors) as float.hex, in a fixed order."""
    if isinstance(x, dict):
        for k in sorted(x, key=str):
            out.append(str(k)); flat(x[k], out)
    elif isinstance(x, (list, tuple)):
        for v in x:
            flat(v, out)
    elif isinstance(x, torch.Tensor):
        flat(x.detach().cpu().numpy(), out)
    elif isinstance(x, np.ndarray):
        out.extend(float(v).hex() for v in x.astype(np.float64).ravel())
    elif isinstance(x, (bool, np.bool_)) or x is None or isinstance(x, str):
        out.append(repr(x))
    elif isinstance(x, (int, float, np.floating, np.integer)):
        out.append(float(x).hex())
    else:
        out.append(repr(x))
    return out

def digest(x):
    return hashlib.sha256("\n".join(flat(x, [])).encode()).hexdigest()

def series(model, values, n, T, seed):
    from torchtea.noise import simulate_model
    return simulate_model(model, values, n_steps=n, h=H, inputs={"temperature": T},
                          generator=torch.Generator().manual_seed(seed))[0, 0].numpy()

out = {}
if case == "components":
    from torchtea.noise import default_values, parse_model, temperature_profile
    from torchtea.noise.components import COMPONENTS
    from torchtea.fitting.exact import exact_loglik
    T = temperature_profile(2000, H, generator=torch.Generator().manual_seed(0))
    omega = torch.linspace(0.01, 3.1, 64, dtype=torch.float64)
    t = torch.arange(2000, dtype=torch.float64) * H
    for name, comp in COMPONENTS.items():
        try:  # (how check treats an effect as a candidate: registered apart in the newer code, on the class before)
            from torchtea.checking.screens import screening_of
            candidate = screening_of(comp).candidate
        except ImportError:
            candidate = comp.candidate
        if name in ("fractional", "white") or not candidate:
            continue
        token = "spikes:3" if name == "spikes" else name
        try:
            model = parse_model(f"fractional+white+{token}")
        except ValueError as exc:
            out[name] = {"refused": str(exc)}
            continue
        v = default_values(model, H, T)
        vt = {k: torch.tensor([x], dtype=torch.float64) for k, x in v.items()}
        row = {"values": v}
        if model.stationary:
            row["spectrum"] = model.spectrum(vt, omega, H)
        row["mean"] = model.mean(vt, t, {"temperature": T})
        y = series(model, v, 2000, T, 1)
        row["series"] = y
        row["loglik"] = exact_loglik(model, v, y, H, inputs={"temperature": T.numpy()})
        out[name] = {"digest": digest(row), "loglik": float(np.asarray(row["loglik"]).ravel()[0])}
elif case == "fit":
    from torchtea.fitting.mle import fit_series
    from torchtea.noise import default_values, temperature_profile
    model = "fractional+white+random-walk"
    T = temperature_profile(6000, H, generator=torch.Generator().manual_seed(0))
    v = default_values(model, H)
    v["random-walk.sigma"] = 2e-3
    y = series(model, v, 6000, T, 3)
    f = fit_series(model, [y], H)[0]
    row = {"values": f.values, "se": f.se, "ci95": f.ci95, "loglik": f.loglik, "exact": f.loglik_exact, "n": f.n}
    out = {"digest": digest(row), "values": f.values, "loglik_exact": f.loglik_exact}
elif case == "check":
    from torchtea.checking import check
    from torchtea.noise import default_values, temperature_profile
    truth = "fractional+white+sinusoid+temperature-bias"
    T = temperature_profile(6000, H, generator=torch.Generator().manual_seed(7))
    v = default_values(truth, H, T)
    v.update({"sinusoid.frequency_hz": 3.37, "sinusoid.amplitude": 8e-3, "temperature-bias.bias_per_degC": 0.01})
    y = series(truth, v, 6000, T, 7)
    d = check(y, H, model="fractional+white", inputs={"temperature": T.numpy()}).as_dict()
    for k in ("seconds", "seconds_this_step", "steps"):
        d.pop(k, None)
    for s in d["screens"]:
        s.pop("seconds", None)
    out = {"digest": digest(d), "screens": [[s["effect"], s.get("statistic"), s.get("p_value")] for s in d["screens"]],
           "suggestions": [[s["effect"], s["gain"]] for s in d["suggestions"]]}
elif case == "loop":
    from torchtea.checking import check
    from torchtea.noise import default_values, parse_model, temperature_profile
    truth = parse_model("fractional+white+temperature-order+step+spikes:3")
    T = temperature_profile(6000, H, generator=torch.Generator().manual_seed(11))
    v = default_values(truth, H, T)
    v.update({"temperature-order.order_per_degC": 0.03, "step.size": 0.05, "step.t_step": 31.0,
              "spikes.size1": -0.3, "spikes.size2": 0.3, "spikes.size3": -0.3})
    y = series(truth, v, 6000, T, 11)
    r = check(y, H, model="fractional+white", inputs={"temperature": T.numpy()}, intervals=False)
    r = r.auto(intervals=False, max_steps=4)
    docs = []
    for st in r.steps:
        d = st.as_dict()
        for k in ("seconds", "seconds_this_step", "steps"):
            d.pop(k, None)
        for s in d["screens"]:
            s.pop("seconds", None)
        docs.append(d)
    out = {"digest": digest(docs), "path": [st.model.spec for st in r.steps], "loop_end": r.loop_end}
elif case == "starts":
    from torchtea.fitting.innovations import located_intervals
    from torchtea.fitting.mle import regress_mean, whittle_fit
    from torchtea.noise import default_values, parse_model, temperature_profile
    from torchtea.noise.components import COMPONENTS
    try:  # the starts registered apart (after issue 47's move) or on the classes (before it)
        from torchtea.fitting.starts import initial_values, starts_of
        hook = lambda c, name: (lambda *a: getattr(starts_of(c), name)(c, *a))
    except ImportError:
        initial_values = lambda m, y, h: m.initial_values(y, h)
        hook = lambda c, name: getattr(c, name)
    T = temperature_profile(2000, H, generator=torch.Generator().manual_seed(0))
    base = parse_model("fractional+white")
    vb = default_values(base, H)
    for name, comp in COMPONENTS.items():
        if name in ("fractional", "white"):
            continue
        token = "spikes:3" if name == "spikes" else name
        try:
            model = parse_model(f"fractional+white+{token}")
        except ValueError:
            continue
        label = model.components[-1][0]
        v = default_values(model, H, T)
        if name == "step":
            v["step.t_step"] = 7.0  # (its typical time, 100 s, is past these 20 s)
        y = series(model, v, 2000, T, 2)
        row = {"initial": initial_values(model, torch.as_tensor(y), H),
               "regress": regress_mean(model, y, H, {"temperature": T.numpy()}),
               "strengths": hook(comp, "strengths")(label, base, vb, H, len(y)),
               "vanishing": hook(comp, "vanishing")(label, base, vb, H, len(y))}
        if model.stationary:
            wf = whittle_fit(model, [y - y.mean()], H, inputs=[{"temperature": T.numpy()}])
            row["whittle"] = [wf.values, wf.loglik]
        if comp.located:
            row["located"] = located_intervals(model, v, y, H, {"temperature": T.numpy()})
        out[name] = digest(row)
elif case == "tea":
    from dataclasses import replace
    from torchtea import SCENARIOS, Structure, gaussian_input, get_preset, make_params, run_tea, simulate
    from torchtea.core.memory import parse_memory
    from torchtea.engines.tea import TEAStream
    from torchtea.noise import simulate_model
    FW = {"fractional.order": 0.4, "fractional.pole": -2.0, "fractional.q": 0.02, "white.r": 1e-3}
    y = simulate_model("fractional+white", FW, n_steps=1500, h=H, realisations=3,
                       generator=torch.Generator().manual_seed(1))[0].unsqueeze(-1)
    cfg = get_preset("paper-mems-x")
    soe = replace(cfg, memory=replace(cfg.memory, kind="soe"))
    branches = replace(cfg, memory=parse_memory("window:40"), kfx_uncertainty="paper-gain",
                       estimate_uncertainty="constant-truth", kfo=replace(cfg.kfo, R="innovation"))
    fields = ("alpha", "P_alpha", "w", "P_w", "x", "P", "innovation", "innovation_cov")
    def arrays(r):
        return {k: getattr(r, k) for k in fields if getattr(r, k, None) is not None}
    for name, c, engine in (("torch exact", cfg, "torch"), ("torch soe", soe, "torch"), ("numba soe", soe, "numba"),
                            ("numba branches", branches, "numba"), ("torch branches", branches, "torch")):
        out[name] = digest(arrays(run_tea(y, h=H, params=make_params(c, Structure()), engine=engine)))
    sc = SCENARIOS["paper-example1"]
    u = gaussian_input((2,), sc.n_steps, 1, sc.input_std, generator=torch.Generator().manual_seed(11))
    s = simulate(Structure(), n_steps=sc.n_steps, h=sc.h, order=sc.order, parameters=[sc.param], process_noise=sc.q,
                 measurement_noise=sc.r, inputs=u, generator=torch.Generator().manual_seed(12))
    p1 = make_params(get_preset("paper-example1"), Structure())
    out["paper example 1"] = digest(arrays(run_tea(s.y, h=sc.h, params=p1, inputs=u)))
    stream = TEAStream(h=H, params=make_params(soe, Structure()))
    steps = [stream.step(y[0, k]) for k in range(300)]
    out["stream"] = digest([[getattr(part, k) for part in o for k in part._fields
                             if isinstance(getattr(part, k), torch.Tensor)] for o in steps])
elif case == "tea_exact":
    from dataclasses import replace
    from torchtea.noise import simulate_model
    from torchtea.noise.tea import tea_view
    from torchtea.noise.tea_exact import run_tea_exact
    GROWN = "fractional+white+random-walk"
    V = {"fractional.order": 0.4, "fractional.pole": -2.0, "fractional.q": 0.02, "white.r": 1e-5, "random-walk.sigma": 0.05}
    y = simulate_model(GROWN, V, n_steps=400, h=H, realisations=3, generator=torch.Generator().manual_seed(5))[0]
    y = y - y.mean(-1, keepdim=True)
    y[1, 200] = float("nan")
    def view(values, **kfo):
        v = tea_view(GROWN, values, H)
        cfg = replace(v.config, memory=replace(v.config.memory, kind="soe"), kfx_filter="exact",
                      kfo=replace(v.config.kfo, **dict({"R": "innovation", "Q0": 1e-5}, **kfo)),
                      kfw=replace(v.config.kfw, R="innovation", Q0=1e-3, P0=0.05))
        return replace(v, config=cfg)
    start = dict(V, **{"fractional.order": 0.3, "fractional.pole": -1.5})
    fields = ("x", "P", "alpha", "P_alpha", "w", "P_w", "innovation", "innovation_cov", "diverged", "diverged_at",
              "memory_clamped")
    def arrays(r):
        return {k: getattr(r, k) for k in fields if getattr(r, k, None) is not None}
    v = view(start, P0=2e-3)
    out["separate"] = digest(arrays(run_tea_exact(v, y, h=H)))
    out["joint"] = digest(arrays(run_tea_exact(replace(v, config=replace(v.config, kfo_kfw="joint")), y, h=H)))
    per = [view(dict(start, **{"fractional.order": a}), P0=p0) for a, p0 in ((0.3, 2e-3), (0.35, 1e-3), (0.5, 4e-3))]
    out["per series"] = digest(arrays(run_tea_exact(per, y, h=H)))
    num = view(start, P0=2e-3, R=1e-4)
    num = replace(num, config=replace(num.config, kfw=replace(num.config.kfw, R=1e-4)))
    out["numeric R"] = digest(arrays(run_tea_exact(num, y[0], h=H)))
elif case == "cli":
    import contextlib, io
    from torchtea.cli import main
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        main(["fit", "--samples", "3000", "--bootstrap", "0", "--json"])
    doc = json.loads(buf.getvalue())
    doc.pop("seconds"); doc.pop("command", None); doc.pop("meaning", None)
    doc.pop("recording")  # the bundled file's path, inside each tree
    out = {"digest": digest(doc), "bic": {a: x["bic"] for a, x in doc["axes"].items()}}
elif case == "export":
    import contextlib, io, pathlib, tempfile
    from torchtea.cli import main
    from torchtea.noise import default_values, simulate_model
    from torchtea.sensors.io import write_columns
    work = pathlib.Path(tempfile.mkdtemp())
    m = "fractional+white+random-walk"
    ys = [simulate_model(m, default_values(m, H), n_steps=6000, h=H, generator=torch.Generator().manual_seed(s))[0, 0]
          .numpy() for s in (1, 2)]
    csv = write_columns(work / "imu.csv", {"t": np.arange(6000) * H, "ax": ys[0], "gx": ys[1]})
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        main(["export", str(csv), "--units", "ms2,rad/s", "--format", "all", "--model", m, "--nees", "8",
              "--no-plots", "--out", str(work / "out")])
    for f in sorted((work / "out").iterdir()):
        text = f.read_text().replace(str(work), "W")
        if f.name == "export.json":
            doc = json.loads(text)
            for k in ("command", "meaning", "recording", "topic"):
                doc.pop(k, None)
            text = json.dumps(doc, sort_keys=True)
        out[f.name] = hashlib.sha256(text.encode()).hexdigest()
print(json.dumps(out))
'''


def run(tree: Path, case: str) -> dict:
    code = f"import sys; sys.path.insert(0, {str(tree)!r})\n" + CHILD
    res = subprocess.run([sys.executable, "-c", code, case], capture_output=True, text=True, cwd=tempfile.gettempdir(),
                         env={"MPLBACKEND": "Agg", "PATH": "/usr/bin:/bin", "HOME": str(Path.home())})
    if res.returncode:
        raise RuntimeError(f"{case} in {tree}: {res.stderr[-2000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--old", required=True, help="the git revision of the code before the refactor")
    ap.add_argument("--cases", default="components,fit,check,loop,cli,starts,tea,tea_exact,export")
    args = ap.parse_args()
    new = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    if subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", ".",
                       ":!experiments/refactor/same_bits.json"], cwd=ROOT, capture_output=True, text=True).stdout.strip():
        new += " + uncommitted changes"
    old_dir = Path(tempfile.mkdtemp(prefix="same-bits-old-"))
    subprocess.run(["git", "worktree", "add", "--detach", str(old_dir), args.old], cwd=ROOT, check=True,
                   capture_output=True)
    results, same = {"old": args.old, "new": new, "cases": {}}, True
    try:
        for case in args.cases.split(","):
            a, b = run(old_dir, case), run(ROOT, case)
            equal = a == b
            same &= equal
            results["cases"][case] = {"equal": equal, "old": a, "new": b}
            print(f"{case:12s} {'the same, bit for bit' if equal else 'DIFFERENT'}")
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(old_dir)], cwd=ROOT, capture_output=True)
    (HERE / "same_bits.json").write_text(json.dumps(results, indent=1) + "\n")
    print(f"{args.old} → {new}: {'every output the same' if same else 'outputs differ'}; written {HERE / 'same_bits.json'}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
