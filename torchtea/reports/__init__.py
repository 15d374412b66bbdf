"""What a user reads: the identification of a recording (:mod:`.identify`) and its report (:mod:`.report`); the
strict JSON and figure helpers they use are :mod:`torchtea.render`. The command line is :mod:`torchtea.cli`.

Its layer is the applications' (with :mod:`torchtea.studies`, :mod:`torchtea.identification`,
:mod:`torchtea.estimation`, the recorder and live mode): it may import every library layer below, never the
command line."""
