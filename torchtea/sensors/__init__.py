"""Real sensors: recordings and their formats (:mod:`.io`; their text, delimiters and time stamps :mod:`.text`), the serial protocol (:mod:`.protocol`), the
recorder (:mod:`.recorder`), a fake device on a pty (:mod:`.fakeimu`), live estimation (:mod:`.live`) and
the checks of missing samples and time stamps (:mod:`.datacheck`).

Two layers live here: the reading of recordings (:mod:`.io`, :mod:`.text`, :mod:`.datacheck`, :mod:`.faults`,
:mod:`.measurements`, :mod:`.protocol`) is the lowest, with :mod:`torchtea.core`, and may import nothing of torchtea
above it; the recorder, the fake device and live mode are applications and may import every library layer."""
