"""What a user reads: the identification of a recording (:mod:`.identify`) and its report (:mod:`.report`); the
strict JSON and figure helpers they use are :mod:`torchtea.render`. The command line is :mod:`torchtea.cli`."""
