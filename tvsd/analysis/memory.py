"""How much memory the doctor needs for a recording, and a refusal in one line when it is not there.

The doctor holds every candidate's columns on the regression rows (the band-limited, decimated
samples: 250 per second at 1 kHz, 500 at 2 kHz) and, while it calibrates the decision, their
whitened basis and its DFT: its peak is the interpreter's fixed part plus the resonance scan's
null (a block of periodograms, bounded) plus a few copies of rows × columns (docmem.md and
memflake.md in docs/measurements measure them). A recording whose estimate exceeds the memory
this process may still take is refused before the analysis (exit 2), saying how many minutes of
it would fit, instead of being killed by the kernel part-way.
"""

from __future__ import annotations

import math
import resource
from pathlib import Path

from tvsd.analysis import design as D
from tvsd.analysis import linescan as L
from tvsd.analysis.dataset import Dataset
from tvsd.analysis.prep import Band
from tvsd.errors import DataFileError

BASE_MIB = 240.0  # the interpreter with numpy, scipy, numba, the kernels (232 MiB alone), small arrays
COPIES = 5.0  # float64 copies of rows × columns at the peak: 3.8–5.5 measured (docmem.md)
# float64 arrays of the line scan's null block alive at once (LineScan.null_peaks, in place): the
# block and its floor (tracemalloc: 2.00–2.02 blocks' size; 5.0 before memrate.md)
NULL_ARRAYS = 2.0
HEADROOM = 0.8  # of the memory available: the rest for the page cache and other processes


def columns(rate_hz: float) -> int:
    """The candidates' columns (design._options at most): imbalance 2, cogging 2 per order,
    two thresholds' scans, one delay per sample up to MAX_DELAY_S, friction asymmetry 2, drift 3."""
    delays = max(2, round(D.MAX_DELAY_S * rate_hz)) - 1
    return 2 + 2 * (D.MAX_COGGING_ORDER - 1) + 2 * D.N_THRESHOLDS + delays + 2 + 3 + 8  # + the baseline's


def rows(n_samples: int, band: Band) -> int:
    return math.ceil(n_samples / max(band.decim, 1))


def null_mib(n_samples: int, band: Band) -> float:
    """The resonance scan's null: NULL_CHUNK periodograms of the rows' ordinates at a time, at most
    NULL_CHUNK_VALUES ordinates (linescan.null_peaks): it grows with the rows up to 40 s at 1 kHz
    (31 MiB), then stays."""
    ordinates = rows(n_samples, band) // 2 + 1
    per_block = max(1, min(L.NULL_CHUNK, L.NULL_CHUNK_VALUES // ordinates)) * ordinates
    return NULL_ARRAYS * 8.0 * per_block / 2**20


def copies_mib(n_samples: int, rate_hz: float, band: Band) -> float:
    """COPIES float64 copies of rows × columns: the part that grows with the record without bound."""
    return COPIES * 8.0 * rows(n_samples, band) * columns(rate_hz) / 2**20


def doctor_mib(n_samples: int, rate_hz: float, band: Band) -> float:
    """What the analysis allocates above the interpreter and its kernels (BASE_MIB), MiB: the part
    of the estimate a machine's page cache does not change (tvsd.analysis.bench measures it)."""
    return null_mib(n_samples, band) + copies_mib(n_samples, rate_hz, band)


def estimate_mib(n_samples: int, rate_hz: float, band: Band) -> float:
    """The doctor's estimated peak resident memory for n_samples at rate_hz, MiB."""
    return BASE_MIB + doctor_mib(n_samples, rate_hz, band)


def available_mib() -> float:
    """What this process may still take: the least of MemAvailable, the cgroup's limit less its
    use, and the address-space limit; inf when none can be read."""
    out = math.inf
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                out = min(out, int(line.split()[1]) / 1024.0)
    except (OSError, ValueError):
        pass
    try:
        cg = Path("/sys/fs/cgroup")
        limit = (cg / "memory.max").read_text().strip()
        if limit != "max":
            out = min(out, (int(limit) - int((cg / "memory.current").read_text())) / 2**20)
    except (OSError, ValueError):
        pass
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        out = min(out, soft / 2**20)
    return out


def check(data: Dataset, band: Band, available: float | None = None) -> None:
    """DataFileError (exit 2) when the estimate exceeds HEADROOM of the memory available."""
    have = available_mib() if available is None else available
    n, rate = len(data.t), data.sample_rate_hz
    need = estimate_mib(n, rate, band)
    if need <= HEADROOM * have:
        return
    per_min = copies_mib(round(60 * rate), rate, band)
    null_max = NULL_ARRAYS * 8.0 * L.NULL_CHUNK_VALUES / 2**20  # the null's bound, whatever the stretch
    fit_min = max((HEADROOM * have - BASE_MIB - null_max) / per_min, 0.0)
    raise DataFileError(
        f"{data.path or data.name}: {n / rate / 60:.1f} min at {rate:g} Hz needs about {need / 1024:.1f} GiB "
        f"for the doctor ({per_min:.0f} MiB per minute), more than the {have / 1024:.1f} GiB this machine "
        f"has free; analyse a stretch of at most {math.floor(fit_min)} min (the rows of one part of the file)"
    )
