"""tracemalloc peak of LineScan.null_peaks in null blocks, and a hash of its draws, at the rows of
20 s, 60 s and 600 s of 1 kHz (docs/measurements/memrate.md): run on two codes, same hashes."""

import hashlib
import tracemalloc

import numpy as np

from tvsd.analysis import calibrate as C
from tvsd.analysis import linescan as L
from tvsd.analysis import memory
from tvsd.analysis.prep import Band

for n in (20_000, 60_000, 600_000):
    f = np.fft.rfftfreq(memory.rows(n, Band()), 1 / 250.0)
    scan = L.LineScan(f, (f > 1.0) & (f < 80.0), 41)
    tracemalloc.start()
    got = scan.null_peaks(np.random.default_rng(3), C.BOOTSTRAP)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    block = max(1, min(L.NULL_CHUNK, L.NULL_CHUNK_VALUES // len(f))) * len(f) * 8
    digest = hashlib.sha1(got.tobytes()).hexdigest()[:12]
    print(n, f"peak {peak / 2**20:.1f} MiB = {peak / block:.3f} blocks", digest)
