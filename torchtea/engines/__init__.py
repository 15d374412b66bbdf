"""The paper's engines on its DFVOSS model structure (:mod:`.structure`): the Triple Estimation Algorithm
(:mod:`.tea`; its settings as tensors :mod:`.params`, its filters' linear algebra :mod:`.unscented`, its memory of
the past states :mod:`.history`, its arguments and stored steps :mod:`.batch`, what it returns :mod:`.results`), its compiled scalar engine (:mod:`.fast`), its
settings as dataclasses (:mod:`.settings`), TOML (:mod:`.config`) and named presets (:mod:`.presets`). The simulator (the paper's scalar model among every noise model's) is
:mod:`torchtea.noise.simulate`; the noise-model engines — the exact Kalman filter and the Whittle likelihood — are
in :mod:`torchtea.likelihood`.

Its layer is above the core and the reading of recordings: it may import :mod:`torchtea.core`,
:mod:`torchtea.render` and :mod:`torchtea.sensors`' readers (``io``, ``datacheck``, ``measurements``), nothing of the
noise models, likelihoods, fits or checks (:mod:`torchtea.noise` imports it, not the other way)."""
