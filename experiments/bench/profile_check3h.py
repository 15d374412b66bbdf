"""Where a 3-hour check's time goes: ``check`` of one channel of the reach benchmark's simulated six-axis
recording (2.16·10⁶ samples at 200 Hz, its temperature given) under cProfile, the check's stage timings first.

    python experiments/bench/reach.py --only check3h               # makes $TMPDIR/torchtea-bench/imu3h.csv
    python experiments/bench/profile_check3h.py 1 fractional+white+random-walk > profile_check3h_ax_fwrw.txt
    python experiments/bench/profile_check3h.py 4 fractional+white > profile_check3h_gx_fw.txt

Arguments: the CSV column (1 = ax … 6 = gz) and the model. One channel's check, so numba's and torch's threads
as the environment sets them (the committed profiles: ax with NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1 beside the
hidden-effect study; gx with the default two threads beside light jobs).
"""
import cProfile
import pstats
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from torchtea.checking import check

col = int(sys.argv[1]) if len(sys.argv) > 1 else 1
model = sys.argv[2] if len(sys.argv) > 2 else "fractional+white+random-walk"
data = np.loadtxt(Path(tempfile.gettempdir()) / "torchtea-bench" / "imu3h.csv", delimiter=",", skiprows=1,
                  usecols=(col, 7))
y, T = data[:, 0], data[:, 1]
pr = cProfile.Profile()
pr.enable()
t = time.perf_counter()
r = check(y, 0.005, model=model, inputs={"temperature": T})
print("total", time.perf_counter() - t, r.timings, r.failed, [s.effect for s in r.suggestions])
pr.disable()
pstats.Stats(pr).sort_stats("cumulative").print_stats(35)
