"""The paper's engines on its DFVOSS model structure (:mod:`.structure`): the Triple Estimation Algorithm
(:mod:`.tea`), its settings as dataclasses (:mod:`.settings`), TOML (:mod:`.config`) and named presets
(:mod:`.presets`), and the scalar-model simulator (:mod:`.simulate`). The noise-model engines — the exact
Kalman filter and the Whittle likelihood — are in :mod:`torchtea.likelihood`."""
