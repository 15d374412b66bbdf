"""Monte Carlo studies of the TEA (:mod:`.montecarlo`), their TensorBoard logs (:mod:`.tblog`) and the
process tuning of long runs (:mod:`.perf`)."""
