"""`tvsctl analyze` on a 20 s, 1 kHz SIL staircase with k more float64 copies of rows × columns
held through it, measured as `tvsctl bench --only doctor_long` measures (memflake.md):

    PYTHONPATH=. PY scripts/memflake_extra_copy.py
"""

import os
import sys
import tempfile
from pathlib import Path

from tvsd.analysis import bench, memory
from tvsd.analysis.benchchild import run_child
from tvsd.analysis.prep import Band

SECONDS, RATE = 20, 1000.0


def main() -> None:
    tmp = Path(tempfile.mkdtemp())
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp / "numba-cache")}
    rec = tmp / "rec.csv"
    run_child([sys.executable, "-c", bench._RECORD_AT, str(rec), str(SECONDS), f"{RATE:g}"], env)
    run_child([sys.executable, "-c", bench._LOAD_KERNELS], env)
    n = round(SECONDS * RATE)
    copy_mib = 8.0 * memory.rows(n, Band()) * memory.columns(RATE) / 2**20
    est = memory.doctor_mib(n, RATE, Band())
    old = memory.COPIES * copy_mib  # the estimate's increment before the null was counted
    analyze = f"sys.argv = ['tvsctl', 'analyze', {str(rec)!r}, '--json', '--quiet']\n"
    analyze += "runpy.run_module('tvsd.cli.main', run_name='__main__')"
    print(f"one copy {copy_mib:.2f} MiB; estimate of the analysis's own {est:.1f} MiB, old {old:.1f}")
    for k in (0, 1, 2, 3):
        code = (
            f"import runpy, sys\nimport numpy as np\nheld = np.ones({round(k * copy_mib * 2**17)})\n{analyze}"
        )
        c = run_child([sys.executable, "-c", code], env, bench._IMPORT_DOCTOR)
        verdict = "passes" if c.own_mib <= est else "FAILS"
        old_verdict = "passes" if c.own_mib <= 1.1 * old else "FAILS"
        print(
            f"copies held {k}: own {c.own_mib:.1f} MiB (peak anon {c.peak_anon_mib:.1f}, base "
            f"{c.base_anon_mib:.1f}, peak RSS {c.peak_rss_mib:.0f}); check {verdict}; old x1.1 {old_verdict}"
        )


if __name__ == "__main__":
    main()
