"""tvsd — controller daemon, simulator and model doctor of the TVS laser scanner."""

from tvsd._kernel_cache import point_numba_cache

__version__ = "0.1.0"

point_numba_cache()  # before any module imports numba: its kernels must not outlive their sources
