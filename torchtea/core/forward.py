"""Forward-mode derivatives (:func:`torch.func.jvp`, :func:`torch.func.jacfwd`) as the package calls them.

On its first forward-mode call torch loads its own derivative rules for it (``torch._decomp.decompositions_for_jvp``)
and builds them with ``torch.jit.script``, which recent versions of torch deprecate: the deprecation warning
(a ``DeprecationWarning`` or a ``FutureWarning``, by version) is about torch's code, not the user's, and nothing a
user of torchtea can act on. It is set aside here, for that one loading only; every other warning, torch's
included, reaches the user as before."""
from __future__ import annotations

import functools
import warnings

import torch

__all__ = ["jvp", "jacfwd"]


@functools.cache
def _load_rules() -> None:
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"`torch\.jit\.script` is deprecated")
        import torch._decomp.decompositions_for_jvp  # noqa: F401  (torch's forward-mode rules, loaded once)


def jvp(func, primals, tangents, **kw):
    """:func:`torch.func.jvp`."""
    _load_rules()
    return torch.func.jvp(func, primals, tangents, **kw)


def jacfwd(func, *args, **kw):
    """:func:`torch.func.jacfwd`."""
    _load_rules()
    return torch.func.jacfwd(func, *args, **kw)
