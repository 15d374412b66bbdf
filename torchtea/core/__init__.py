"""The numerical core every engine shares: Grünwald–Letnikov coefficients and differences (:mod:`.gl`), the
history-sum memories — exact, exponential-sum, window — and their one dispatch (:mod:`.memory`), and the
statistics of estimates and innovations (:mod:`.stats`), forward-mode derivatives as the package calls them
(:mod:`.forward`).

The lowest layer, with :mod:`torchtea.render`: it may import numpy, torch, scipy and numba, nothing of torchtea
above it; every other layer may import it."""
