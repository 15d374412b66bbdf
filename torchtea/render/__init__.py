"""How numbers leave torchtea: strict JSON (:mod:`.strictjson`: NaN and infinities as null, atomic writes) and the
figures' common helpers (:mod:`.plots`). The lowest layer with :mod:`torchtea.core`: any module may use it, it uses
no other part of torchtea."""
