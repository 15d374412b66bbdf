"""Are the hidden effects of ``hidden.py`` hidden from the time plot and visible in their own view?

    python experiments/check/views.py          # → views.png, views.json

For seed 0 of each effect, the recording with the effect and the same recording without it (the same noise
draws: the effect's parameter at its null value — amplitude 0, σ 0, β 0, γ 0, a cut-off far above Nyquist)
are drawn side by side: left the raw time plot (what a person looks at first), right the view the effect shows
in (Welch spectrum, overlapping Allan deviation, 10-s means against temperature, 10-s variances against
temperature). ``views.json`` holds two numbers per effect: the effect's share of the time plot — the sd of
(with − without) over the sd of the recording, and the ratio of the two recordings' sds — and the largest change it makes in its view (a ratio of
spectra or ADEVs, or a fitted slope against temperature), with what that change is measured against.
"""
from __future__ import annotations

import json
from pathlib import Path

import allantools
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.signal import welch  # noqa: E402

from torchtea.studies.hidden import HIDDEN_STRENGTH, hidden_case  # noqa: E402

HERE = Path(__file__).resolve().parent
H = 0.01
NULL = {"random-walk": {"random-walk.sigma": 0.0}, "sinusoid": {"sinusoid.amplitude": 0.0},
        "temperature-bias": {"temperature-bias.bias_per_degC": 0.0},
        "temperature-order": {"temperature-order.order_per_degC": 0.0}, "low-pass": {"low-pass.cutoff_hz": 1e6}}


def windows(x, n):
    k = len(x) // n
    return x[:k * n].reshape(k, n)


def main():
    effects = [e for e in HIDDEN_STRENGTH if e != "none"]
    fig, axes = plt.subplots(len(effects), 2, figsize=(12, 2.6 * len(effects)))
    out = {}
    for row, e in zip(axes, effects):
        y, T, _ = hidden_case(e, 0)
        y0, T0, _ = hidden_case(e, 0, strength={**HIDDEN_STRENGTH[e], **NULL[e]})
        assert np.array_equal(T, T0)
        t = np.arange(len(y)) * H
        share = float(np.std(y - y0) / np.std(y0))
        ax = row[0]
        ax.plot(t, y0 - y0.mean() + 0.25, lw=0.3, color="0.4", label="without (offset +0.25)")
        ax.plot(t, y - y0.mean(), lw=0.3, color="C0", label=f"with {e}")
        ax.set(xlabel="t (s)", ylabel="m/s²", title=f"{e}: time plot (effect's sd / recording's sd = {share:.2f})")
        ax.legend(loc="upper right", fontsize=7)
        ax = row[1]
        if e in ("sinusoid", "low-pass"):
            f, p = welch(y, fs=1 / H, nperseg=4096)
            _, p0 = welch(y0, fs=1 / H, nperseg=4096)
            ax.loglog(f[1:], p0[1:], color="0.4", label="without")
            ax.loglog(f[1:], p[1:], color="C0", label="with")
            ax.set(xlabel="Hz", ylabel="PSD (m/s²)²/Hz", title="Welch spectrum (4096-sample segments)")
            ratio = p[1:] / p0[1:]
            view = {"view": "Welch PSD with/without", "max_ratio": float(ratio.max()), "min_ratio": float(ratio.min()),
                    "segments_scatter": f"±{1 / np.sqrt(2 * len(y) // 4096):.0%} (1 sd of a Welch estimate of {2 * len(y) // 4096} segments)"}
        elif e == "random-walk":
            taus = np.logspace(-2, 2, 25)
            tt, ad, _, _ = allantools.oadev(y, rate=1 / H, data_type="freq", taus=taus)
            _, ad0, _, _ = allantools.oadev(y0, rate=1 / H, data_type="freq", taus=tt)
            ax.loglog(tt, ad0, color="0.4", label="without")
            ax.loglog(tt, ad, color="C0", label="with")
            ax.set(xlabel="τ (s)", ylabel="ADEV (m/s²)", title="overlapping Allan deviation")
            view = {"view": "ADEV with/without", "max_ratio": float((ad / ad0).max()), "at_tau_s": float(tt[np.argmax(ad / ad0)])}
        elif e == "temperature-bias":
            m, m0, Tm = (windows(x, 1000).mean(axis=1) for x in (y, y0, T))
            ax.plot(Tm, m0 - m0.mean(), "o", ms=3, color="0.4", label="without")
            ax.plot(Tm, m - m0.mean(), "o", ms=3, color="C0", label="with")
            ax.set(xlabel="temperature (°C)", ylabel="10-s mean (m/s²)", title="10-s means against temperature")
            s, s0 = (float(np.polyfit(Tm, x, 1)[0]) for x in (m, m0))
            view = {"view": "slope of 10-s means on temperature (m/s²/°C)", "with": s, "without": s0}
        else:  # temperature-order
            v, v0 = windows(np.diff(y), 1000).var(axis=1), windows(np.diff(y0), 1000).var(axis=1)
            Tm = windows(T[1:], 1000).mean(axis=1)
            ax.plot(Tm, v0, "o", ms=3, color="0.4", label="without")
            ax.plot(Tm, v, "o", ms=3, color="C0", label="with")
            ax.set(xlabel="temperature (°C)", ylabel="variance of Δy, 10-s windows", title="10-s variances against temperature")
            s, s0 = (float(np.polyfit(Tm, np.log(x), 1)[0]) for x in (v, v0))
            view = {"view": "slope of log 10-s variance of Δy on temperature (1/°C)", "with": s, "without": s0}
        ax.legend(loc="best", fontsize=7)
        out[e] = {"strength": HIDDEN_STRENGTH[e], "time_plot_share": share,
                  "sd_ratio_with_without": float(np.std(y) / np.std(y0)), **view}
        print(e, json.dumps(out[e]))
    fig.tight_layout()
    fig.savefig(HERE / "views.png", dpi=110)
    (HERE / "views.json").write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
