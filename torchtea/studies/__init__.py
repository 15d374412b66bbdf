"""Monte Carlo studies of the TEA (:mod:`.montecarlo`; a study's result as one form, :mod:`.results`) and their
TensorBoard logs (:mod:`.tblog`); the model check's studies: records with hidden effects (:mod:`.hidden`) and the
oracle that judges the loop against what the exact likelihood can tell (:mod:`.oracle`).

Its layer is the applications': it may import every library layer below (the TEA, the noise models, the fits),
never the command line."""
