"""What a user reads: the identification of a recording (:mod:`.identify`), its report (:mod:`.report`),
plots (:mod:`.plots`) and strict JSON (:mod:`.strictjson`). The command line is :mod:`torchtea.cli`."""
