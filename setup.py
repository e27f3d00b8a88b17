"""The two build steps pyproject.toml cannot express (the metadata lives there).

1. The protocol spec ships in the wheel: firmware/protocol.yaml is copied to
   tvsd/hw/mcu/protocol.yaml, where tvsd/hw/mcu/spec.py finds it outside a source checkout; so do
   the shipped configs (config/*.yaml → tvsd/config/shipped/, the parameter sets `default` and
   `paper` when neither $TVSD_CONFIG_DIR nor /etc/tvsd has them: tvsd/config/load.py).
2. The firmware core is compiled for the host at build time (never at run time): the portable C core
   (firmware/core) with the host board layer (firmware/board/host) becomes tvsd/sim/_vmcu*.so, the
   library tvsd/sim/vmcu_library.py loads with ctypes for `tvsd --sil` and `tvsctl mcu ... --sil`.
   Its protocol header is generated first by firmware/gen_protocol.py, which reads protocol.yaml with
   tvsd's own parser. The wheel is therefore platform-specific (it holds a shared object).

Needs a C compiler (gcc) and PyYAML at build time (pyproject.toml [build-system]).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
SPEC = "firmware/protocol.yaml"
CORE = ["crc32", "frame", "pulse", "stepper", "outputs", "dispatch", "core"]


class BuildPy(build_py):
    """Also copy the protocol spec and the shipped configs into the package."""

    def run(self) -> None:
        super().run()
        target = Path(self.build_lib) / "tvsd" / "hw" / "mcu" / "protocol.yaml"
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(ROOT / SPEC, target)
        shipped = Path(self.build_lib) / "tvsd" / "config" / "shipped"
        shipped.mkdir(parents=True, exist_ok=True)
        for cfg in sorted((ROOT / "config").glob("*.yaml")):
            shutil.copyfile(cfg, shipped / cfg.name)


class BuildExt(build_ext):
    """Generate protocol_gen.h before compiling the core; the .so has no Python entry point."""

    def build_extension(self, ext: Extension) -> None:
        gen_dir = Path(self.build_temp).resolve() / "protocol"
        gen_dir.mkdir(parents=True, exist_ok=True)
        subprocess.run(
            [sys.executable, str(ROOT / "firmware" / "gen_protocol.py"), "--out",
             str(gen_dir / "protocol_gen.h"), str(ROOT / SPEC)],
            check=True,
        )
        ext.include_dirs.insert(0, str(gen_dir))
        super().build_extension(ext)

    def get_export_symbols(self, ext: Extension) -> list[str]:
        return []  # loaded with ctypes, not imported: no PyInit_ symbol to export


vmcu = Extension(
    "tvsd.sim._vmcu",
    sources=[f"firmware/core/{n}.c" for n in CORE] + ["firmware/board/host/board.c"],
    include_dirs=["firmware/core", "firmware/board/host"],
    define_macros=[("BOARD_ID", "BOARD_ID_HOST"), ("CORE_TX_RING", "8192u"), ("CORE_SIL_HOOKS", None)],
    extra_compile_args=["-std=gnu11", "-fvisibility=hidden", "-Wall", "-Wextra"],
    libraries=["m"],
)

setup(ext_modules=[vmcu], cmdclass={"build_py": BuildPy, "build_ext": BuildExt})
