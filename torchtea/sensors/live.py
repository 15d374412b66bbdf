"""Live estimation while recording: the TEA on the three accelerometer axes as one batch.

The recorder hands every chunk of rows to :meth:`LiveEstimator.put` (never blocks); a worker thread
converts them to m/s², spends the first ``warmup_s`` seconds of each segment measuring each axis's
mean and variance (the mean is removed and the variance sets R, Rᵒ, Rʷ, as ``identify`` does), then
steps a :class:`~torchtea.engines.tea.TEAStream` per sample and writes TensorBoard scalars at least once per
``log_every_s``: ``order/<axis>``, ``param/<axis>``, ``innovation/<axis>`` (latest),
``innovation_rms/<axis>`` (since the last write), ``live/lag_samples`` (samples waiting) and
``live/steps_per_s``. A new segment (device reset) restarts the estimate.
"""
from __future__ import annotations

import math
import queue
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from ..core.memory import parse_memory
from ..engines.structure import Structure
from ..engines.tea import TEAStream, make_params, stack_params
from ..identification import axis_configs
from ..reports.identify import AXES
from .recorder import physical_row

__all__ = ["LiveEstimator"]

#: Samples the stream's ``soe`` kernel is designed for (5.5 h at 100 Hz).
HORIZON = 2_000_000


class LiveEstimator:
    def __init__(self, logdir, *, memory: str = "soe", warmup_s: float = 2.0, log_every_s: float = 1.0,
                 horizon: int = HORIZON, clock=time.monotonic):
        """``clock()`` gives the time in seconds that ``log_every_s`` is measured on (the wall clock; tests pass
        a clock that advances with the samples, so that when the estimator logs does not depend on how fast
        the machine is)."""
        self._clock = clock
        self.logdir = Path(logdir)
        self.memory = parse_memory(memory)
        if not self.memory.bounded:
            raise ValueError("live estimation needs bounded memory: --memory soe or window:L")
        self.warmup_s, self.log_every_s, self.horizon = warmup_s, log_every_s, horizon
        self._q: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self.summary: dict | None = None
        self.error: str | None = None
        self.steps = 0
        self.max_lag = 0
        self._queued = 0
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name="torchtea-live", daemon=True)
        self._thread.start()

    # -- recorder side
    def put(self, rows, headers) -> None:
        hdr = dict(headers)
        data = [(r.segment, r.counter, math.nan, math.nan, math.nan) if r.sample is None
                else (r.segment, r.counter, *physical_row(r.sample.values, hdr[r.segment].scale)[:3]) for r in rows]
        rate = {s: h.scale["rate_hz"] for s, h in hdr.items()}
        with self._lock:
            self._queued += len(data)
        self._q.put((np.asarray(data, dtype=np.float64), rate))

    def close(self, timeout: float | None = None) -> dict | None:
        """Process what is queued, stop, and return the final summary (``lag_at_close_samples``: how many
        samples were still waiting when the recording stopped — bounded when the estimator keeps up)."""
        with self._lock:
            self.lag_at_close = self._queued
        self._q.put(None)
        self._thread.join(timeout)
        return self.summary

    # -- worker
    def _run(self) -> None:
        from torch.utils.tensorboard import SummaryWriter

        self._writer = SummaryWriter(log_dir=str(self.logdir))
        self._segment = None
        self._t_start = self._clock()
        try:
            while True:
                item = self._q.get()
                if item is None:
                    break
                data, rate = item
                for row in data:
                    self._sample(row, rate)
                    with self._lock:
                        self._queued -= 1
                        self.max_lag = max(self.max_lag, self._queued)
        except Exception as exc:  # noqa: BLE001 — the recording must go on; say what happened
            self.error = f"{type(exc).__name__}: {exc}"
            import sys

            print(f"torchtea record: live estimation stopped ({self.error}); recording continues", file=sys.stderr)
        finally:
            self._log()
            self._writer.close()
            self.summary = self._summary()

    def _sample(self, row, rate) -> None:
        seg = int(row[0])
        if seg != self._segment:
            self._segment = seg
            self._h = 1.0 / rate[seg]
            self._warm = []
            self._stream = None
            self._k0 = None
            self._writer.add_text("live/segments", f"segment {seg} started (rate {rate[seg]:g} Hz)", self.steps)
        y = row[2:5]
        if self._stream is None:
            self._warm.append(y)
            if len(self._warm) * self._h >= self.warmup_s:
                self._start()
            return
        self._step(y)

    def _start(self) -> None:
        warm = np.asarray(self._warm)  # (W, 3)
        if np.isnan(warm).all(axis=0).any():
            return  # not a single sample on some axis yet: keep warming up
        self._mean = np.nanmean(warm, axis=0)
        yw = torch.as_tensor((warm - self._mean).T.copy()).unsqueeze(-1)
        cfgs = [replace(c, memory=self.memory) for c in axis_configs(yw)]
        self._configs = cfgs
        params = stack_params([make_params(c, Structure()) for c in cfgs])
        self._stream = TEAStream(h=self._h, params=params, batch=(3,), horizon=self.horizon)
        self._innov_sq = np.zeros(3)
        self._innov_n = np.zeros(3)
        self._last_log = 0.0
        self._t_steps = self._clock()
        self._k_steps = 0
        for y in self._warm:  # the warm-up samples are estimated too
            self._step(y)
        self._warm = []

    def _step(self, y) -> None:
        yk = torch.as_tensor(y - self._mean).unsqueeze(-1)
        carry, out = self._stream.step(yk)
        e = out.innovation[:, 0].numpy()
        seen = ~np.isnan(y)
        self._innov_sq += np.where(seen, e * e, 0.0)
        self._innov_n += seen
        self._last = carry, out
        self.steps += 1
        self._k_steps += 1
        if self._clock() - self._last_log >= self.log_every_s:
            self._log()

    def _log(self) -> None:
        """Write the latest estimates (called from :meth:`_step` once ``log_every_s`` has passed, and at the end)."""
        stream = getattr(self, "_stream", None)
        if stream is None or stream.k == 0:
            return
        now = self._clock()
        carry, out = self._last
        k = stream.k - 1
        w = self._writer
        for i, a in enumerate(AXES):
            w.add_scalar(f"order/{a}", float(carry.alpha[i, 0]), k)
            w.add_scalar(f"param/{a}", float(carry.w[i, 0]), k)
            w.add_scalar(f"innovation/{a}", float(out.innovation[i, 0]), k)
            if self._innov_n[i]:
                w.add_scalar(f"innovation_rms/{a}", math.sqrt(self._innov_sq[i] / self._innov_n[i]), k)
        with self._lock:
            w.add_scalar("live/lag_samples", self._queued, k)
        dt = now - self._t_steps
        if dt > 0:
            w.add_scalar("live/steps_per_s", self._k_steps / dt, k)
        w.flush()
        self._innov_sq[:] = 0
        self._innov_n[:] = 0
        self._last_log = now

    def _summary(self) -> dict:
        out = {"steps": self.steps, "max_lag_samples": self.max_lag,
               "lag_at_close_samples": getattr(self, "lag_at_close", None), "logdir": str(self.logdir),
               "seconds": round(self._clock() - self._t_start, 3)}
        if self.error:
            out["error"] = self.error
        stream = getattr(self, "_stream", None)
        if stream is not None and stream.k:
            carry = stream.carry
            out["segment"] = self._segment
            out["axes"] = {a: {"alpha": float(carry.alpha[i, 0]), "param": float(carry.w[i, 0]),
                               "R": float(self._configs[i].kfx.R), "diverged": bool(carry.diverged[i])}
                           for i, a in enumerate(AXES)}
        return out

    def describe(self) -> str:
        s = self.summary or {}
        if "axes" not in s:
            return f"live: no estimate (fewer than {self.warmup_s:g} s of samples)"
        lines = [f"live: {s['steps']} samples estimated, at most {s['max_lag_samples']} waiting"]
        lines += [f"  {a}: α̂ = {v['alpha']:.4f}, ŵ = {v['param']:.4f}" + (" DIVERGED" if v["diverged"] else "")
                  for a, v in s["axes"].items()]
        return "\n".join(lines)
