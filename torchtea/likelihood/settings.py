"""Which likelihood engines the fits use: the fast ones by default, today's reference ones on request.

The fast engines give the reference engines' answers (the tests hold them to each other); the reference ones
are kept to check that, and for benchmarks that time both in one run::

    from torchtea.likelihood.settings import using
    with using(exact="riccati", whittle="full"):
        result = check(y, h)          # the covariance update of every sample, every Fourier frequency
"""
from __future__ import annotations

import contextlib
import contextvars
from dataclasses import dataclass, replace

__all__ = ["LikelihoodSettings", "current", "using"]


@dataclass(frozen=True)
class LikelihoodSettings:
    """``exact``: the compiled exact filter's engine (``"auto"``: Chandrasekhar recursions for a time-invariant
    model, the Riccati covariance update otherwise; ``"riccati"``: always the latter). ``whittle``: ``"binned"``
    (the periodogram averaged in log-spaced bins, :mod:`.whittle`) or ``"full"`` (every Fourier frequency)."""

    exact: str = "auto"
    whittle: str = "binned"


_CURRENT = contextvars.ContextVar("torchtea_likelihood", default=LikelihoodSettings())  # noqa: B039 (frozen)


def current() -> LikelihoodSettings:
    """The settings in force."""
    return _CURRENT.get()


@contextlib.contextmanager
def using(**changes):
    """Within the block, the likelihood settings with ``changes`` (fields of :class:`LikelihoodSettings`)."""
    token = _CURRENT.set(replace(_CURRENT.get(), **changes))
    try:
        yield current()
    finally:
        _CURRENT.reset(token)
