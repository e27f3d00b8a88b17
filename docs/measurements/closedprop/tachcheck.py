"""For each file: is the speed replaced by the encoder, and would the recorded speed pass check_moving?"""
import sys
from pathlib import Path
from tvsd.config import load_config
from tvsd.analysis.dataset import load
from tvsd.analysis import speed_source, excitation, absorber
from tvsd.analysis import design as D
from tvsd.analysis.prep import Band, prepare
from tvsd.errors import DataFileError
cfg = load_config()
for name in sys.argv[1:]:
    try:
        d = load(Path(name), cfg)
        ch = speed_source.choose(d, Band())
        if ch is d:
            print(Path(name).stem, "kept"); continue
        p = prepare(ch, Band())
        cols = absorber.absorb(D.build(p, ch.offset_term, True)).X.shape[1]
        m, n, s = excitation.moving_rows(p)
        pr = prepare(d, Band())
        mr, nr, sr = excitation.moving_rows(pr)
        print(Path(name).stem, "switched need", 10 * cols, "enc", m, "rec", mr, "of", nr, "REFUSED" if mr < 10 * cols else "ok", flush=True)
    except DataFileError as e:
        print(Path(name).stem, "error", str(e)[:80])
