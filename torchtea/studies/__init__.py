"""Monte Carlo studies of the TEA (:mod:`.montecarlo`; a study's result as one form, :mod:`.results`), their TensorBoard logs (:mod:`.tblog`) and the
process tuning of long runs (:mod:`.perf`).

Its layer is the applications': it may import every library layer below (the TEA, the noise models, the fits),
never the command line."""
