"""Several recordings of one sensor fitted together: one noise model whose noise parameters every recording shares,
each recording with its own mean terms (its level, its ramp, its temperature's bias) and its own references and
located times — the likelihood the sum of the recordings' exact likelihoods (:func:`fit_together`).

Then, per noise parameter, whether the recordings agree on it: the likelihood-ratio of "its own value in each
recording" against "one value in all", χ² with R − 1 degrees of freedom for R recordings, each parameter tested at
the level over the number of parameters (Bonferroni: the verdict "the recordings agree" is wrong in at most that
share of collections of one law). And from three recordings on, the spread of the bias from one power-up to the next
(turn-on repeatability, :func:`bias_repeatability`): each recording's level — the constant its exact filter estimates
at the pooled noise parameters, with its standard error — and the spread between them beyond those errors, by
restricted maximum likelihood with a profile-likelihood interval.

The pooled fit climbs by the method of scoring (:func:`~.scoring.score`) with each recording's exact gradient and
information from the sensitivity filter, assembled over the joint coordinates; a recording with missing samples or a
temperature-driven order has no sensitivity gradient, and the pooled likelihood is then maximised by L-BFGS-B on
central differences. It starts from every recording's own fit and from their average, and keeps the best."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy import optimize, stats

from ..noise.components import MeanEffect
from ..noise.model import NoiseModel, parse_model
from .exact import FIT_MEMORY, centred, gradient_supported
from .mle import fit_series
from .results import Fit, bic, intervals_from_hessian
from .scoring import FD_STEP, INFORMATION_STEP, fd_hessian, logit_limits, objective, score, scoring_objective

__all__ = ["Together", "fit_together", "bias_repeatability", "TOGETHER_LEVEL", "REPLICATES_MEANING"]

#: The family level of the test that the recordings agree on every noise parameter.
TOGETHER_LEVEL = 0.05

#: What ``replicates`` in a JSON document means (:meth:`Together.as_dict`).
REPLICATES_MEANING = {
    "replicates": "several recordings fitted together: one noise model shared by all, each recording its own mean "
                  "terms; per noise parameter a likelihood-ratio test of one value in all against its own in each",
    "recordings": "the recordings, in the order given",
    "loglik_together": "the pooled exact log-likelihood: noise parameters shared",
    "loglik_separate": "the sum of the recordings' own fits' exact log-likelihoods: every parameter its own",
    "parameters": "per noise parameter: the likelihood-ratio statistic, its degrees of freedom (recordings − 1), "
                  "p_value, differs (p below the threshold: the family level over the parameters tested), given (the "
                  "parameters already each recording's own when it was tested: the most significant is freed first, "
                  "and the others tested again beside it), the pooled value with its interval, and each recording's "
                  "own value with its interval",
    "verdict": "agree: no parameter differs at the family level; differ: the parameters named differ",
    "bias_repeatability": "from three recordings on: each recording's level (its exact filter's estimate of the "
                          "constant at the pooled noise values, with its standard error) and the spread of the level "
                          "between recordings beyond those errors (the turn-on bias repeatability, 1σ) with its 95 % "
                          "profile-likelihood interval; an accelerometer's level holds gravity's projection, so it "
                          "says nothing of repeatability where the recordings' mountings differ",
}


@dataclass
class Together:
    """:func:`fit_together`'s result: the pooled fit (``values`` per recording, the shared noise parameters the same in
    each; ``ci95`` of the shared ones), each recording's own fit (``separate``), the per-parameter tests
    (``parameters``), and the turn-on repeatability (``bias``, None below three recordings)."""

    model: NoiseModel
    recordings: list
    shared: list
    own: list
    values: list
    loglik: float
    se: dict
    ci95: dict
    separate: list
    parameters: list
    level: float
    threshold: float
    bias: dict | None = None
    notes: list = field(default_factory=list)
    #: the pooled likelihood (its joint coordinates) and its maximum there, for tests that regroup a parameter
    pooled: tuple | None = field(default=None, repr=False)
    #: the pooled observed information at that maximum over the joint coordinates (None: not computed, or not finite)
    information: np.ndarray | None = field(default=None, repr=False)
    #: whether the per-parameter tests ran (``fit_together(tests=False)``: the pooled maximum alone)
    tested: bool = True

    @property
    def finite(self) -> bool:
        """Whether the pooled likelihood is finite at the fit (a recording without a finite ℓ makes it −1e300)."""
        return math.isfinite(self.loglik) and self.loglik > -1e299

    @property
    def n(self) -> int:
        """The samples of all the recordings."""
        return int(sum(f.n for f in self.separate))

    @property
    def k(self) -> int:
        """The estimates: the shared parameters once, each recording's own mean terms and held estimates (a step's
        time) once per recording."""
        return len(self.shared) + len(self.recordings) * (len(self.own) + len(self.model.held_estimates()))

    @property
    def bic(self) -> float:
        """BIC of the pooled fit on the pooled exact likelihood (what the loop on several recordings compares)."""
        return bic(self.k, self.n, self.loglik)

    def repeatability(self) -> dict:
        """The turn-on bias repeatability (:func:`bias_repeatability`) where there are three or more recordings, else
        its place held: ``spread`` None, the recordings named (a datasheet's value is then not compared)."""
        if self.bias is not None:
            return self.bias
        return {"spread": None, "ci95": None, "levels": [{"recording": n} for n in self.recordings]}

    def as_fit(self, r: int = 0, h: float | None = None) -> Fit:
        """The pooled model as recording ``r``'s fit (what an export or a datasheet's verdict takes): the shared noise
        parameters' pooled values, that recording's own mean terms, and intervals from the pooled information — the
        covariance of that recording's coordinates, the others' own terms profiled out —; ``h`` the sample time."""
        if self.pooled is None or h is None:
            raise ValueError("the pooled fit's intervals need its joint coordinates and the sample time")
        joint, x = self.pooled
        P = len(self.model.names)
        u = joint.unpack(x, r)[0]
        H = torch.zeros(P, P, dtype=torch.float64)
        idx = torch.tensor(joint.free, dtype=torch.int64)
        c = joint.columns(r)
        try:
            if self.information is None or not np.all(np.linalg.eigvalsh(self.information) > 0):
                raise np.linalg.LinAlgError
            Hr = np.linalg.inv(np.linalg.inv(self.information)[np.ix_(c, c)])
        except np.linalg.LinAlgError:
            Hr = np.full((len(c), len(c)), -1.0)  # (not positive definite: no interval)
        H[idx[:, None], idx[None, :]] = torch.as_tensor(Hr)
        mask = torch.zeros(P, dtype=torch.bool)
        mask[idx] = True
        values, se, ci, how = intervals_from_hessian(self.model, u, H, mask, h)
        values = dict(self.values[r])
        own = self.separate[r]
        ll_r = -float(joint.neg_loglik_of(r, x))  # (recording r's share of the pooled ℓ: its ℓ at the pooled values)
        fit = Fit(self.model, "exact", values, se, ci, how, ll_r, ll_r, own.n,
                  [self.model.names[i] for i in joint.free], self.finite,
                  notes=[f"pooled over {len(self.recordings)} recordings ({', '.join(self.recordings)}): the noise "
                         f"parameters from all of them, with the pooled intervals; the mean terms "
                         f"{self.recordings[r]}'s; loglik its exact log-likelihood at the pooled values"],
                  u=u.detach().clone(), hessian=H)
        fit.count({n: w for n, w in self.model.held_estimates().items()})
        return fit

    @property
    def differs(self) -> list:
        """The noise parameters whose values differ between the recordings at the family level."""
        return [p["name"] for p in self.parameters if p["differs"]]

    @property
    def verdict(self) -> str:
        if not self.tested:
            return "not tested (the pooled fit alone)"
        if not self.differs:
            return f"the {len(self.recordings)} recordings agree: one noise model for all"
        return "the recordings differ in " + ", ".join(self.differs)

    def as_dict(self) -> dict:
        return {"recordings": list(self.recordings), "model": self.model.spec, "shared": list(self.shared),
                "own": list(self.own), "loglik_together": self.loglik,
                "loglik_separate": float(sum(_exact_loglik(f) for f in self.separate)),
                "level": self.level, "threshold": self.threshold, "parameters": self.parameters,
                "verdict": "not tested" if not self.tested else "differ" if self.differs else "agree",
                "differs": self.differs,
                "summary": self.verdict, "bias_repeatability": self.bias, "notes": list(self.notes)}


class _Joint:
    """The pooled likelihood over joint coordinates: each free coordinate of the model (an index into its names) has
    one value per group of recordings — ``groups[i]`` ``(R,)`` the group of each recording: all 0 for a parameter
    every recording shares, 0 … R − 1 for one each recording has its own, 0 before and 1 after a change —; every
    other coordinate at that recording's ``bases`` value."""

    def __init__(self, model, ys, h, inputs, bases, groups: dict):
        self.model, self.ys, self.h, self.inputs, self.bases = model, ys, h, inputs, bases
        self.R = len(ys)
        self.free = sorted(groups)
        self.groups = {i: np.asarray(groups[i], dtype=np.int64) for i in self.free}
        self.offset, k = {}, 0
        for i in self.free:
            self.offset[i] = k
            k += int(self.groups[i].max()) + 1 if len(self.groups[i]) else 1
        self.D = k
        self.exact_gradient = all(gradient_supported(model, y) is None for y in ys)
        # each recording's exact −ℓ (and gradient, information) over its free coordinates, the others at its base
        idx = np.array(self.free, dtype=np.int64)
        self._values = [objective(model, y, h, b.clone(), idx, inp, FIT_MEMORY) for y, b, inp in zip(ys, bases, inputs)]
        self._vgi = ([scoring_objective(model, y, h, b.clone(), idx, inp, FIT_MEMORY)
                      for y, b, inp in zip(ys, bases, inputs)] if self.exact_gradient else None)

    @classmethod
    def split(cls, model, ys, h, inputs, bases, shared, own):
        R = len(ys)
        return cls(model, ys, h, inputs, bases, {**{i: np.zeros(R) for i in shared}, **{i: np.arange(R) for i in own}})

    def columns(self, r: int) -> np.ndarray:
        """The joint position of each of recording ``r``'s free coordinates (in :attr:`free`'s order)."""
        return np.array([self.offset[i] + self.groups[i][r] for i in self.free], dtype=np.int64)

    def unpack(self, points: np.ndarray, r: int) -> torch.Tensor:
        points = np.atleast_2d(points)
        U = self.bases[r].repeat(len(points), 1)
        U[:, self.free] = torch.as_tensor(points[:, self.columns(r)])
        return U

    def pack(self, us: list) -> np.ndarray:
        """Joint coordinates from one unconstrained vector per recording (each group's value: the mean of its
        recordings')."""
        x = np.zeros(self.D)
        for i in self.free:
            g = self.groups[i]
            for k in range(int(g.max()) + 1):
                x[self.offset[i] + k] = np.mean([float(us[r][i]) for r in range(self.R) if g[r] == k])
        return x

    def neg_loglik(self, points: np.ndarray) -> np.ndarray:
        """The pooled −ℓ ``(K,)`` at K joint points; 1e300 where a recording's ℓ is not finite."""
        points = np.atleast_2d(points)
        f = sum(values(points[:, self.columns(r)]) for r, values in enumerate(self._values))
        return np.minimum(f, 1e300)

    def neg_loglik_of(self, r: int, x: np.ndarray) -> float:
        """Recording ``r``'s −ℓ at the joint point ``x``."""
        return float(self._values[r](np.atleast_2d(x)[:, self.columns(r)])[0])

    def vgi(self, points: np.ndarray):
        """−ℓ ``(K,)``, its gradient ``(K, D)`` and the scoring information ``(K, D, D)`` (sums of the recordings';
        1e300, zero gradient and information where a recording's ℓ is not finite)."""
        K = len(points)
        f, g, info = np.zeros(K), np.zeros((K, self.D)), np.zeros((K, self.D, self.D))
        for r, vgi in enumerate(self._vgi):
            c = self.columns(r)
            fr, gr, ir = vgi(points[:, c])
            f += fr
            g[:, c] += gr
            info[:, c[:, None], c[None, :]] += ir
        bad = f >= 1e299
        return (np.where(bad, 1e300, f), np.where(bad[:, None], 0.0, g), np.where(bad[:, None, None], 0.0, info))

    def limits(self) -> np.ndarray:
        owner = [i for i in self.free for _ in range(int(self.groups[i].max()) + 1)]
        return logit_limits(self.model, np.array(owner, dtype=np.int64))

    def maximise(self, starts: list) -> tuple[np.ndarray, float]:
        """The best of the climbs from ``starts`` (joint coordinates): its point and ℓ."""
        X0 = np.clip(np.stack(starts), -self.limits(), self.limits())
        if self.exact_gradient:
            X, f, _, _ = score(lambda p, rows: self.vgi(p), lambda p, rows: self.neg_loglik(p), X0, self.limits())
        else:
            X, f = [], []
            bounds = [(-b, b) if math.isfinite(b) else (None, None) for b in self.limits()]
            for x0 in X0:
                res = optimize.minimize(self._value_and_gradient, x0, jac=True, method="L-BFGS-B", bounds=bounds,
                                        options={"maxiter": 500})
                X.append(res.x)
                f.append(res.fun)
            X, f = np.array(X), np.array(f)
        best = int(np.argmin(f))
        return X[best], -float(f[best])

    def _value_and_gradient(self, x: np.ndarray) -> tuple[float, np.ndarray]:
        """−ℓ at ``x`` and its gradient by central differences (one batch of 1 + 2D points)."""
        E = np.eye(self.D) * FD_STEP
        f = self.neg_loglik(np.concatenate([x[None], x + E, x - E]))
        return float(f[0]), (f[1:self.D + 1] - f[self.D + 1:]) / (2 * FD_STEP)

    def information(self, x: np.ndarray) -> np.ndarray | None:
        """The observed information (Hessian of −ℓ) at ``x``: central differences of the exact gradients, or second
        central differences of the likelihood where there are none; None where a point of them has no finite
        likelihood."""
        D = self.D
        values = []  # (every −ℓ the differences took, to refuse a point without a finite one)
        if self.exact_gradient:
            E = np.eye(D) * INFORMATION_STEP
            f, g, _ = self.vgi(np.concatenate([x + E, x - E]))
            values.append(f)
            H = (g[:D] - g[D:]) / (2 * INFORMATION_STEP)
        else:
            def batch(points):
                values.append(self.neg_loglik(points))
                return values[-1]

            H = fd_hessian(batch, x)
        if not all(np.all(f < 1e299) for f in values):
            return None
        return 0.5 * (H + H.T)


def _common_references(model, separate: list, h: float) -> list:
    """Each recording's unconstrained values from its own fit, with every reference (a temperature's ``t_ref``) at one
    value for all — the recordings' values weighted by their samples —: a temperature-driven order's α₀ is then the
    order at one temperature in every recording, and each recording's level the bias there."""
    refs = [n for n in model.names if n in model.references()]
    if not refs:
        return [f.u.detach().clone() for f in separate]
    weights = np.array([f.n for f in separate], dtype=np.float64)
    common = {n: float(np.average([f.values[n] for f in separate], weights=weights)) for n in refs}
    return [model.to_unconstrained({n: [common.get(n, x)] for n, x in f.values.items()}, h)[0] for f in separate]


def _with(u: torch.Tensor, source: torch.Tensor, idx) -> torch.Tensor:
    """``u`` with its coordinates ``idx`` taken from ``source``."""
    out = u.clone()
    out[list(idx)] = source[list(idx)]
    return out


def _values(model, U: torch.Tensor, h: float) -> dict:
    return {n: float(x) for n, x in zip(model.names, model.as_matrix(model.from_unconstrained(U, h))[0])}


def fit_together(model, series: list, h: float, *, inputs: list | None = None, recordings: list | None = None,
                 level: float = TOGETHER_LEVEL, separate: list | None = None, repeatability: bool = True,
                 tests: bool = True, starts: list | None = None, progress=None) -> Together:
    """Fit ``model`` to several recordings (``series``: 1-D arrays of one channel, NaN = missing; ``inputs`` one dict
    or None per recording) with its noise parameters shared and its mean parameters each recording's own; then test,
    per noise parameter, whether the recordings agree on it, and (three or more) their bias's spread.
    ``separate``: the recordings' own fits, where already made (their exact likelihood is what the pooled one is held
    against). ``tests``: the shared parameters' intervals and the per-parameter tests (without them, the pooled
    maximum alone: what a loop comparing models needs). ``starts``: more places to climb from, each one unconstrained
    vector per recording (an earlier pooled maximum). ``progress(line)`` takes what it is doing."""
    model = parse_model(model)
    say = progress or (lambda line: None)
    given = starts
    R = len(series)
    if R < 2:
        raise ValueError("fitting together needs two or more recordings")
    inputs = [None] * R if inputs is None else list(inputs)
    names = list(recordings) if recordings is not None else [f"recording {r + 1}" for r in range(R)]
    ys = [centred(model, y) for y in series]
    if separate is None:
        separate = []
        for r, y in enumerate(series):
            say(f"fitting {names[r]} on its own")
            separate.append(fit_series(model, [y], h, inputs=None if inputs[r] is None else [inputs[r]])[0])
    kinds = {n: dict(model.components)[n.rsplit(".", 1)[0]].kind for n in model.names}
    held = model.held_estimates()  # (a step's time, a line's frequency: each recording's own, where its fit put it)
    free = [i for i, n in enumerate(model.names) if n in separate[0].free and n not in held]
    shared = [i for i in free if kinds[model.names[i]] != "mean"]
    own = [i for i in free if kinds[model.names[i]] == "mean"]
    bases = _common_references(model, separate, h)
    joint = _Joint.split(model, ys, h, inputs, bases, shared, own)
    say(f"fitting the {R} recordings together")
    # from each recording's own noise values and from their average, each recording's own mean terms beside them
    starts = [joint.pack([_with(u, bases[r], shared) for u in bases]) for r in range(R)] + [joint.pack(bases)]
    starts += [joint.pack([torch.as_tensor(u, dtype=torch.float64) for u in us]) for us in given or ()]
    x, ll = joint.maximise(starts)
    notes = []
    sum_separate = float(sum(_exact_loglik(f) for f in separate))
    if ll > sum_separate + 1e-3 * R:
        notes.append(f"the pooled fit's ℓ ({ll:.2f}) is above the sum of the recordings' own fits' ({sum_separate:.2f}): "
                     "a recording's own fit fell short of its maximum; the tests use the pooled ℓ as the bound")
    values = [_values(model, joint.unpack(x, r), h) for r in range(R)]
    if not tests:
        return Together(model, names, [model.names[i] for i in shared], [model.names[i] for i in own], values, ll, {},
                        {}, separate, [], level, level / max(1, len(shared)), None, notes, (joint, x), tested=False)
    se, ci, how, H = _shared_intervals(model, joint, x, h)
    threshold = level / max(1, len(shared))
    say("testing each noise parameter: one value, or each recording its own")
    tests = _parameter_tests(model, joint, x, ll, shared, separate, h, threshold, se, ci, how)
    by_component: dict = {}
    for t in tests:
        if t["differs"]:
            by_component.setdefault(t["name"].rsplit(".", 1)[0], []).append(t["name"])
    for label, differing in by_component.items():
        if len(differing) > 1:
            notes.append(f"{', '.join(differing)} differ together: a component's parameters trade off against each "
                         f"other (the fractional order, pole and drive along a ridge), so each one freed alone takes "
                         f"up the same difference — read it as {label} differing between the recordings")
    bias = bias_repeatability(model, series, values, h, inputs, names) if R >= 3 and repeatability else None
    return Together(model, names, [model.names[i] for i in shared], [model.names[i] for i in own], values, ll, se,
                    ci, separate, tests, level, threshold, bias, notes, (joint, x), H)


def _exact_loglik(fit) -> float:
    """A recording's own fit's exact log-likelihood (a fit on the long-record path climbs the Whittle one)."""
    return float(fit.loglik_exact if fit.loglik_exact is not None else fit.loglik)


def _shared_intervals(model, joint: _Joint, x: np.ndarray, h: float) -> tuple[dict, dict, dict, np.ndarray | None]:
    """Intervals of the parameters every recording shares from the pooled observed information (the recordings' own
    coordinates profiled out: the shared block of its inverse), and that information."""
    H = joint.information(x)
    shared = [i for i in joint.free if not joint.groups[i].any()]
    pos = [joint.offset[i] for i in shared]
    u = joint.unpack(x, 0)[0]
    P = len(model.names)
    Hfull = torch.zeros(P, P, dtype=torch.float64)
    try:  # (the information must be positive definite as a whole, the recordings' own coordinates too)
        if H is None or not np.all(np.linalg.eigvalsh(H) > 0):
            raise np.linalg.LinAlgError
        Hs = np.linalg.inv(np.linalg.inv(H)[np.ix_(pos, pos)])
    except np.linalg.LinAlgError:
        Hs = np.full((len(pos), len(pos)), -1.0)  # (not positive definite: no interval)
    idx = torch.tensor(shared, dtype=torch.int64)
    Hfull[idx[:, None], idx[None, :]] = torch.as_tensor(Hs)
    mask = torch.zeros(P, dtype=torch.bool)
    mask[idx] = True
    _, se, ci, how = intervals_from_hessian(model, u, Hfull, mask, h)
    keep = {model.names[i] for i in shared}
    return ({n: v for n, v in se.items() if n in keep}, {n: v for n, v in ci.items() if n in keep},
            {n: v for n, v in how.items() if n in keep}, H)


def regrouped(joint: _Joint, x: np.ndarray, i: int, groups, alternatives: list, each: bool = True
              ) -> tuple[_Joint, np.ndarray, float]:
    """The pooled likelihood's maximum with parameter ``i`` grouped anew (``groups`` ``(R,)``: its own value per
    group of recordings), from the pooled maximum ``x`` and, for each of ``alternatives`` (an unconstrained vector
    per recording), from ``x`` with the parameter there in all recordings (each group at its recordings' mean) and,
    with ``each``, in each recording alone: the best of them."""
    R = joint.R
    new = _Joint(joint.model, joint.ys, joint.h, joint.inputs, joint.bases, {**joint.groups, i: groups})
    at = [joint.unpack(x, r)[0] for r in range(R)]
    starts = [new.pack(at)]
    for us in alternatives:
        for r in range(R if each else 0):
            moved = [u.clone() for u in at]
            moved[r][i] = us[r][i]
            starts.append(new.pack(moved))
        starts.append(new.pack([_with(u, v, [i]) for u, v in zip(at, us)]))
    x2, ll2 = new.maximise(starts)
    return new, x2, ll2


def _parameter_tests(model, joint: _Joint, x: np.ndarray, ll: float, shared: list, separate: list, h: float,
                     threshold: float, se: dict, ci: dict, how: dict) -> list:
    """Per shared parameter, the likelihood ratio of its own value in each recording against one in all, step by
    step: every parameter still shared is tested against the current model, the one of smallest p is freed where that
    p is below ``threshold`` (its test is the one reported) and the others are tested again beside it; the parameters
    left shared report their last test. So a difference in one parameter is not also charged to another that takes it
    up when it is held shared (the random walk when the white level differs); under one law the first step alone
    decides, at the family level."""
    R, df = joint.R, joint.R - 1
    own = [f.u.detach().clone() for f in separate]
    current, cx, cll = joint, x, ll
    remaining, found, freed = list(shared), {}, []
    while remaining:
        trial = {}
        for i in remaining:
            new, x2, ll2 = regrouped(current, cx, i, np.arange(R), [own])
            lr = max(0.0, 2.0 * (ll2 - cll))
            trial[i] = (float(stats.chi2.sf(lr, df)), lr, new, x2, ll2)
        best = max(remaining, key=lambda i: trial[i][1])  # (one df for all: the largest ratio, even where p underflows)
        if trial[best][0] >= threshold:
            for i in remaining:
                found[i] = (trial[i][0], trial[i][1], list(freed), False)
            break
        found[best] = (trial[best][0], trial[best][1], list(freed), True)
        freed.append(model.names[best])
        remaining.remove(best)
        current, cx, cll = trial[best][2], trial[best][3], trial[best][4]
    out = []
    for i in shared:
        p, lr, given, differs = found[i]
        name = model.names[i]
        out.append({"name": name, "statistic": lr, "df": df, "p_value": p, "differs": differs, "given": given,
                    "value": _values(model, joint.unpack(x, 0), h)[name], "se": se.get(name), "ci95": ci.get(name),
                    "ci95_method": how.get(name),
                    "values": [{"value": f.values[name], "se": f.se.get(name), "ci95": f.ci95.get(name)}
                               for f in separate]})
    return out


def _level(model, y: np.ndarray, values: dict, h: float, inputs: dict | None) -> tuple[float, float]:
    """The level of one recording — the constant its exact filter estimates at ``values``, the model's other mean
    terms removed — and its standard error: generalised least squares by the filter's whitening."""
    from .innovations import innovations, whiten

    y = np.asarray(y, dtype=np.float64)
    t = torch.arange(len(y), dtype=torch.float64) * h
    level_names = [f"{lb}.{c.params[0].name}" for lb, c in model.components if isinstance(c, MeanEffect) and c.level]
    v = dict(values)
    for n in level_names:
        v[n] = 0.0
    rest = model.mean(v, t, inputs).numpy()[0]
    inn = innovations(model, values, y, h, inputs)
    w = whiten(inn, np.vstack([y - rest, np.ones_like(y)]))
    ok = np.isfinite(w).all(0)
    wy, w1 = w[0, ok], w[1, ok]
    info = float(w1 @ w1)
    if not info > 0:
        raise ValueError("the recording's level cannot be estimated: no observed sample its filter whitens")
    return float(wy @ w1) / info, 1.0 / math.sqrt(info)


def bias_repeatability(model, series: list, values: list, h: float, inputs: list | None = None,
                       recordings: list | None = None) -> dict:
    """The spread of the level from one recording to the next beyond each level's own standard error: levels
    ``b_r ~ N(μ, σ² + s_r²)``, σ by restricted maximum likelihood, its 95 % interval where the profile restricted
    likelihood falls by χ²₁(0.95)/2 (0 as the lower end where zero is inside)."""
    model = parse_model(model)
    R = len(series)
    inputs = [None] * R if inputs is None else inputs
    names = list(recordings) if recordings is not None else [f"recording {r + 1}" for r in range(R)]
    levels = [_level(model, y, v, h, inp) for y, v, inp in zip(series, values, inputs)]
    b = np.array([lv for lv, _ in levels])
    s2 = np.maximum(np.array([se * se for _, se in levels]), 1e-300)

    def reml(sig2: float) -> float:
        w = 1.0 / (sig2 + s2)
        mu = float(np.sum(w * b) / np.sum(w))
        out = float(-0.5 * (np.sum(np.log(sig2 + s2)) + math.log(np.sum(w)) + np.sum(w * (b - mu) ** 2)))
        return out if math.isfinite(out) else -math.inf

    spread = float(np.var(b, ddof=1)) + float(s2.max())
    hi = max(spread * 100.0, 1e-300)
    grid = np.concatenate([[0.0], np.geomspace(hi * 1e-12, hi, 400)])
    vals = np.array([reml(g) for g in grid])
    k = int(np.argmax(vals))
    if 0 < k < len(grid) - 1:
        res = optimize.minimize_scalar(lambda g: -reml(g), bounds=(grid[k - 1], grid[k + 1]), method="bounded",
                                       options={"xatol": grid[k] * 1e-6})
        sig2, top = float(res.x), -float(res.fun)
    else:
        sig2, top = float(grid[k]), float(vals[k])
    cut = top - 0.5 * float(stats.chi2.ppf(0.95, 1))

    def edge(a: float, c: float) -> float:
        return float(optimize.brentq(lambda g: reml(g) - cut, a, c))

    lo = 0.0 if reml(0.0) >= cut else edge(0.0, sig2)
    upper = sig2 if sig2 > 0 else hi * 1e-12
    while reml(upper) >= cut and upper < hi * 1e6:
        upper *= 4.0
    up = edge(sig2, upper) if reml(upper) < cut else math.inf
    mu_w = 1.0 / (sig2 + s2)
    return {"levels": [{"recording": n, "level": lv, "se": se} for n, (lv, se) in zip(names, levels)],
            "mean": float(np.sum(mu_w * b) / np.sum(mu_w)), "spread": math.sqrt(sig2),
            "ci95": [math.sqrt(lo), math.sqrt(up)], "method": "restricted maximum likelihood, profile interval"}
