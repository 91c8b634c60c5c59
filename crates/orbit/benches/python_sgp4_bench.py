#!/usr/bin/env python3
"""python-sgp4 (Vallado's C++ SGP4 behind `SatrecArray`) propagating one satellite over a day
at 1 s steps: the comparison point for `cargo bench -p m6p-orbit` (sgp4_teme_one_day_1s_steps).

Usage: python3 -m venv /tmp/venv && /tmp/venv/bin/pip install sgp4 numpy
       /tmp/venv/bin/python crates/orbit/benches/python_sgp4_bench.py
Prints propagations per second (best of several runs, single thread).
"""

import time

import numpy as np
from sgp4.api import WGS72, SatrecArray, Satrec, accelerated

# The reference 6U cubesat TLE (CUBESAT-6U in tests/data/teme_to_j2000.csv).
LINE1 = "1 99903U 26012AC  26120.75000000  .00002345  00000-0  12345-3 0  9996"
LINE2 = "2 99903  97.5200  10.5000 0008000 300.0000  60.0000 15.14500000 50009"
DAY_S = 86_400


def main() -> None:
    assert accelerated, "python-sgp4 must use its C++ extension"
    sat = Satrec.twoline2rv(LINE1, LINE2, WGS72)
    array = SatrecArray([sat])
    jd = np.full(DAY_S, sat.jdsatepoch)
    fr = sat.jdsatepochF + np.arange(DAY_S) / 86_400.0
    best = float("inf")
    for _ in range(15):
        t0 = time.perf_counter()
        e, r, v = array.sgp4(jd, fr)
        best = min(best, time.perf_counter() - t0)
    assert not e.any()
    print(f"python-sgp4 {__import__('sgp4').__version__} SatrecArray: {DAY_S} propagations "
          f"in {best * 1e3:.2f} ms = {DAY_S / best / 1e6:.3f} million per second")


if __name__ == "__main__":
    main()
