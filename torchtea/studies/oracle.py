"""The studies' reference for what a record can show: an **oracle** that knows the true structure of a
simulated recording and asks the exact likelihood, not the check, whether each hidden effect is visible beside the
others.

For a recording made by ``base + e₁ + … + e_m`` (:func:`~.hidden.random_case`), the oracle fits the true model and
each model with one hidden effect taken out by exact maximum likelihood, and calls effect eᵢ **resolved** when the
likelihood ratio LR = 2(ℓ_true − ℓ_without eᵢ) passes the check's own screen level: p = P(χ²_df > LR) below
``screen_level`` / (number of candidates screened), df the number of parameters the check would estimate for eᵢ.
An effect that passes that test (``screen``) but gains less than :data:`~torchtea.checking.check.CLOSE_BIC` in BIC (``bic_gain`` =
LR − df·ln n) is one the check cannot keep by its own rule — it keeps an effect that lowers BIC and names a tie
within 6 — so **resolved** asks for both: p under the screen level and a BIC gain of at least CLOSE_BIC. A hidden
effect counts as missed by the check only where the oracle resolves it; where it does not, the record cannot show
it beside the others (or only within the tie window) and the check should say so rather than be scored wrong.

What the oracle is given that the check is not: which effects are there, and the values of what every fit holds
(a line's frequency, a step's time, spike times, temperature references) at the truth. Its χ² reference counts
those held parameters in df, as BIC counts them, though its fit does not search them — conservative for them, where
the check's search makes the real null wider: the two roughly offset, not exactly. The level's divisor is the
fourteen candidates, where a check divides by those it screened in that pass. Where the effect's null leaves a
parameter unidentified (a Gauss–Markov bias at σ = 0 has no τ) the χ² law is not the LR's (Davies' problem): the
BIC condition, not the χ² one, then decides.

Each maximum is the best of several starts (the truth; the base model's own exact fit with the effects at their
true values; for a model with an effect taken out, the true model's maximum without it), and the true model is
also started from every reduced model's maximum with the effect put back, so that ℓ_true ≥ ℓ_without holds up to
the optimiser's tolerance — an optimiser's failure is not taken for evidence.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ..checking.check import CANDIDATES, CLOSE_BIC
from ..fitting.mle import fit_series, refine_best
from ..noise.grammar import token
from ..noise.model import parse_model

__all__ = ["oracle", "effect_df", "status", "judge"]


def _tokens_without(model, label: str) -> str:
    return "+".join(token(c) for lb, c in model.components if lb != label)


def effect_df(model, label: str) -> int:
    """The parameters the check estimates for the component ``label`` of ``model``: all of its parameters but the
    references it holds (a temperature's ``t_ref``)."""
    refs = model.references()
    return sum(1 for n in model.names if n.split(".", 1)[0] == label and n not in refs)


def _fixed(model) -> list:
    """What every fit holds: references, held estimates (a line's frequency) and located times (a step's)."""
    return sorted(set(model.references()) | set(model.held_estimates()) | set(model.located()))


def _restricted(values: dict, model, m, removed: str | None, partial: bool = False) -> dict:
    """``values`` of ``model``'s parameters as ``m``'s (``model`` without the component ``removed``, or ``m`` itself
    for None): each of ``m``'s components takes the values of the one of ``model`` it is (labels are numbered anew
    after a drop: :func:`~torchtea.checking.simplify.carried_labels`). ``partial``: only those ``values`` has."""
    from ..checking.simplify import carried_labels

    carried = carried_labels(model, m, removed) if removed is not None else {lb: lb for lb, _ in m.components}
    out = {}
    for lb, c in m.components:
        for p in c.params:
            src = f"{carried.get(lb, lb)}.{p.name}"
            if src in values:
                out[f"{lb}.{p.name}"] = values[src]
            elif not partial:
                raise KeyError(f"{src}: no value for {lb}.{p.name} of {m.spec}")
    return out


def _put_back(values: dict, model, m, removed: str) -> dict:
    """The values of ``m`` (``model`` without ``removed``) under ``model``'s labels."""
    from ..checking.simplify import carried_labels

    return {f"{old}.{n.split('.', 1)[1]}": v for lb, old in carried_labels(model, m, removed).items()
            for n, v in values.items() if n.split(".", 1)[0] == lb}


def _fit(model, y, h, inputs, starts):
    """The exact fit from ``starts``, its BIC counting what check's counts (held estimates and located times as
    estimated, references not: :meth:`~torchtea.fitting.results.Fit.count`)."""
    fixed = _fixed(model)
    fit, _ = refine_best(model, y, h, starts, inputs=inputs, fixed=fixed, must=[name for name, _ in starts])
    fit.count({**model.held_estimates(), **model.located()})
    return fit


def oracle(y, h: float, truth: dict, model, inputs: dict | None = None, base: str | None = None,
           screen_level: float = 0.05, screened: int | None = None, rivals: dict | None = None) -> dict:
    """What the exact likelihood can tell in ``y`` about each component of the true ``model`` (spec) that is not in
    ``base`` (default: the components the base noise of :func:`~.hidden.random_case` has, ``fractional+white``).
    ``truth``: every parameter's true value. Returns ``{"loglik": ℓ at the true model's maximum, "effects": {label:
    {"name", "df", "loglik_without", "lr", "p", "resolved", "bic_gain"}}, "threshold": the p-value bound}``;
    ``bic_gain`` is the BIC the effect gains beside the others (LR − df·ln n: above 0, BIC keeps it).

    ``rivals``: hidden effect's label → effects that could stand in its place (a Gauss–Markov bias → a random walk).
    Each rival model (the true model with the effect swapped for the rival, not nested in it) is fitted too;
    ``"rivals"`` in the result gives per label and rival its ℓ and ``bic_difference`` (the rival's BIC − the true
    model's): the check cannot tell them apart where that is under :data:`~torchtea.checking.check.CLOSE_BIC`."""
    from .hidden import BASE_MODEL
    model = parse_model(model)
    base = parse_model(base or BASE_MODEL)
    base_names = [c.name for _, c in base.components]
    y = np.asarray(y, dtype=np.float64)
    n = int(np.sum(~np.isnan(y)))
    inp = None if inputs is None else [inputs]
    screened = len(CANDIDATES) if screened is None else screened
    threshold = screen_level / max(1, screened)
    base_fit = fit_series(base, [np.where(np.isnan(y), np.nanmean(y), y)], h, inputs=inp, intervals=False)[0]

    def starts_for(m, removed=None, extra=()):
        t = _restricted(truth, model, m, removed)
        b = {**t, **_restricted(base_fit.values, base, m, None, partial=True)}
        return [("the truth", t), ("the base model's fit, the effects at the truth", b), *extra]

    labels = [lb for lb, c in model.components if c.name not in base_names]
    reduced = {}
    for lb in labels:
        m = parse_model(_tokens_without(model, lb))
        reduced[lb] = (m, _fit(m, y, h, inputs, starts_for(m, lb)))
    back = [(f"without {lb}'s maximum, {lb} put back", {**truth, **_put_back(f.values, model, m, lb)})
            for lb, (m, f) in reduced.items()]
    full = _fit(model, y, h, inputs, starts_for(model, extra=back))
    # each reduced model once more from the true model's maximum (a mode the first starts missed)
    effects = {}
    for lb, (m, f) in reduced.items():
        again = _fit(m, y, h, inputs, [("the true model's maximum without it",
                                        _restricted(full.values, model, m, lb)), ("its own best", dict(f.values))])
        ll0 = max(f.loglik, again.loglik)
        df = effect_df(model, lb)
        lr = max(0.0, 2.0 * (full.loglik - ll0))
        p = float(stats.chi2.sf(lr, df))
        gain = lr - df * math.log(n)
        effects[lb] = {"name": dict(model.components)[lb].name, "df": df, "loglik_without": ll0, "lr": lr, "p": p,
                       "screen": bool(p < threshold), "bic_gain": gain,
                       "resolved": bool(p < threshold and gain >= CLOSE_BIC),
                       "short": bool(full.loglik < ll0 - 1e-3)}  # the true model's fit below a nested one's
    told = {}
    for lb, names in (rivals or {}).items():
        for rival in names:
            told.setdefault(lb, {})[rival] = _rival(model, lb, rival, y, h, inputs, full, reduced[lb][1])
    return {"loglik": full.loglik, "effects": effects, "threshold": threshold, "n": n, "model": model.spec,
            "rivals": told}


def _rival(model, label, rival, y, h, inputs, full, without) -> dict:
    """The true model with ``label`` swapped for ``rival``, fitted from the reduced model's maximum with the rival at
    its typical values and at a tenth and ten times its scale parameters, and from its own exact fit where the
    model is stationary."""
    from ..noise import default_values
    tokens = [token(c) if lb != label else rival for lb, c in model.components]
    m = parse_model("+".join(tokens))
    T = None if inputs is None else inputs.get("temperature")
    typical = default_values(m, h, T)
    starts = []
    for scale in (1.0, 0.1, 10.0):
        v = {**typical, **{k: without.values[k] for k in m.names if k in without.values}}
        for k in m.names:
            if k.startswith(rival + ".") and k not in without.values and k not in m.references():
                v[k] = typical[k] * (scale if any(w in k for w in ("sigma", "amplitude", "size", "bias")) else 1.0)
        starts.append((f"the rest at its maximum without {label}, {rival} at {scale:g}× its typical values", v))
    if m.stationary:
        try:
            f = fit_series(m, [np.where(np.isnan(y), np.nanmean(y), y)], h, inputs=None if inputs is None else [inputs],
                           fixed={k: typical[k] for k in m.references()}, intervals=False)[0]
            starts.append(("its own exact fit", dict(f.values)))
        except ValueError:
            pass
    fit = _fit(m, y, h, inputs, starts)
    d = fit.bic - full.bic
    return {"model": m.spec, "loglik": fit.loglik, "bic_difference": d}


def status(effect: dict, rivals: dict) -> str:
    """What the record shows of one hidden effect (the oracle's ``effects`` entry, its ``rivals``): ``shown``
    (resolved — screen level and BIC gain ≥ CLOSE_BIC — and told apart from every rival), ``tie-rival`` (resolved,
    a rival within CLOSE_BIC of it), ``rival`` (a rival beats it by CLOSE_BIC or more: the record shows the rival),
    ``weak`` (passes the screen level, gains under CLOSE_BIC: with or without it is a tie) or ``hidden``."""
    d = {k: r["bic_difference"] for k, r in rivals.items()}
    if any(v <= -CLOSE_BIC for v in d.values()):
        return "rival"
    if effect["resolved"]:
        return "tie-rival" if any(v < CLOSE_BIC for v in d.values()) else "shown"
    return "weak" if effect.get("screen", effect["resolved"]) else "hidden"


def judge(case: dict, orc: dict) -> dict:
    """One case against its oracle. Per hidden effect its :func:`status`; the loop's end is **right** when for each
    effect: shown → in the end model; tie-rival → it or its rival in the end and a tie naming either; rival → the
    rival in the end; weak → in the end or not, with a tie naming it when not; hidden → not in the end."""
    hidden = list(case["effects"])
    rivals = orc.get("rivals", {})
    end = [t.partition(":")[0] for t in case.get("model", "").split("+")]
    ties = case.get("ties", [])
    named = {e for t in ties for e in t["effects"]}
    st, right = {}, True
    for lb, e in orc["effects"].items():
        name = e["name"]
        st[name] = status(e, rivals.get(lb, {}))
        alts = set(rivals.get(lb, {}))
        if st[name] == "shown":
            ok = name in end
        elif st[name] == "tie-rival":
            ok = bool(({name} | alts) & set(end)) and bool(({name} | alts) & named)
        elif st[name] == "rival":
            ok = bool(alts & set(end))
        elif st[name] == "weak":
            ok = name in end or name in named
        else:
            ok = name not in end
        right = right and ok
    return {"hidden": hidden, "status": st, "all_shown": all(v == "shown" for v in st.values()),
            "ends_with_all": all(e in end for e in hidden), "right": right, "tie": bool(ties),
            "tie_hidden": bool(named & set(hidden)),
            "lr": {e["name"]: e["lr"] for e in orc["effects"].values()},
            "gain": {e["name"]: e["bic_gain"] for e in orc["effects"].values()},
            "rival_bic": {lb: {k: r["bic_difference"] for k, r in rv.items()} for lb, rv in rivals.items()}}
