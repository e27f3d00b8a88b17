"""Copy a recording CSV without its omega_ref column: a phi_ref-only closed-loop file."""
import sys
from pathlib import Path
from tvsd.recording.csvfile import read, write
out = Path(sys.argv[1])
for name in sys.argv[2:]:
    rec = read(Path(name))
    extra = {k: v for k, v in rec.extra.items() if k != "omega_ref"}
    meta = {k: v for k, v in rec.meta.items() if k not in ("tvs-recording", "sample_rate_hz")}
    write(out / Path(name).name, rec.t, rec.u, rec.omega, rec.phi, rec.sample_rate_hz, meta, extra)
