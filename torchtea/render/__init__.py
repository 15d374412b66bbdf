"""How numbers leave torchtea: strict JSON (:mod:`.strictjson`: NaN and infinities as null, atomic writes) and the
figures' common helpers (:mod:`.plots`). The lowest layer with :mod:`torchtea.core`: any module may use it; it may import numpy, torch and
matplotlib, no other part of torchtea."""
