"""The paper's engines on its DFVOSS model structure (:mod:`.structure`): the Triple Estimation Algorithm
(:mod:`.tea`), its settings as dataclasses (:mod:`.settings`), TOML (:mod:`.config`) and named presets
(:mod:`.presets`). The simulator (the paper's scalar model among every noise model's) is
:mod:`torchtea.noise.simulate`; the noise-model engines — the exact Kalman filter and the Whittle likelihood — are
in :mod:`torchtea.likelihood`."""
