"""Real sensors: recordings and their formats (:mod:`.io`), the serial protocol (:mod:`.protocol`), the
recorder (:mod:`.recorder`), a fake device on a pty (:mod:`.fakeimu`), live estimation (:mod:`.live`) and
the checks of missing samples and time stamps (:mod:`.datacheck`)."""
