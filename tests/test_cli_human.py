"""What an operator reads from the daemon commands: local times, flag words, one JSON rule, and a
point stream that says what it waits for (issue 15). A fake daemon on a real socket answers."""

from __future__ import annotations

import asyncio
import json
import re
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tvsd.cli import main as cli
from tvsd.cli.human import FLAG_WORDS, flag_words, local_time
from tvsd.daemon.rpc import ThreadedRpcServer
from tvsd.scan.points import FLAG_NAMES

T_FAULT = 1_795_000_000.123  # the `1.795e+09` of the issue
FAULT = {"t_unix": T_FAULT, "cause": "MCU state frames stopped", "action": "PWM 0", "kind": "link_loss"}
ISO_MS = re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}[+-]\d\d:\d\d")


class Fake:
    def __init__(self, state: str = "scanning", faults: list[dict[str, Any]] | None = None) -> None:
        self.state, self.faults = state, faults or []
        self.delay_s = 0.0

    def table(self) -> dict[str, Any]:
        def answer(result: object) -> Any:
            async def fn(**kw: Any) -> object:
                return result

            return fn

        async def status() -> dict[str, Any]:
            return {"state": self.state, "rps": 20.0, "faults": self.faults, "points": {"per_s": 0.0}}

        async def faults_list() -> list[dict[str, Any]]:
            return self.faults

        async def slow_answer() -> dict[str, Any]:  # a daemon busy for longer than a caller waits
            await asyncio.sleep(self.delay_s)
            return {"recorded": None}

        return {
            "status": status,
            "faults_list": faults_list,
            "faults_clear": answer({"state": "idle"}),
            "speed": answer({"rps_setpoint": 12.5}),
            "scan_start": answer({"state": "scanning"}),
            "scan_stop": answer({"state": "spinning"}),
            "aim": answer({"phi_deg": 60.0, "gamma_deg": 0.0}),
            "aim_xyz": answer({"phi_deg": 60.0, "gamma_deg": 0.0}),
            "gains_get": answer({"Gp": 3.78, "Gd": 3.11, "Gr": 2.0, "G0": 100.0}),
            "gains_set": answer({"gains": {"Gp": 1.0, "Gd": 1.0, "Gr": 1.0, "G0": 1.0}, "warnings": []}),
            "record_start": answer({"recording": "/tmp/rec"}),
            "record_stop": slow_answer,
            "imu_calibrate": answer({"bias": [0.0, 0.0, 0.0]}),
            "shutdown": answer({"state": "stopping"}),
        }


@pytest.fixture
def serve() -> Iterator[Any]:
    servers: list[ThreadedRpcServer] = []
    with tempfile.TemporaryDirectory(prefix="tvs") as tmp:  # sun_path allows 107 bytes only

        def start(fake: Fake) -> Path:
            path = Path(tmp) / f"tvsd{len(servers)}.sock"
            t = ThreadedRpcServer(path, fake.table())
            t.__enter__()
            servers.append(t)
            return path

        yield start
        for t in servers:
            t.__exit__(None, None, None)


def tvsctl(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    status = cli.main(list(argv))
    out, err = capsys.readouterr()
    return status, out, err


def test_flag_words_are_the_point_streams_flags() -> None:
    assert FLAG_WORDS == FLAG_NAMES
    assert flag_words(2) == "compensated" and flag_words(6) == "compensated+no_imu"
    assert flag_words(0) == "none" and flag_words(16) == "bit16"


def test_faults_table_shows_local_iso_time_with_ms(serve: Any, capsys: pytest.CaptureFixture[str]) -> None:
    sock = serve(Fake("fault", [FAULT]))
    status, out, err = tvsctl(capsys, "faults", "--socket", str(sock))
    assert (status, err) == (0, "")
    assert "e+09" not in out and local_time(T_FAULT) in out, out
    zone = time.strftime("%z", time.localtime(T_FAULT))  # +0100 → the ISO form's +01:00
    assert ISO_MS.fullmatch(local_time(T_FAULT)) and local_time(T_FAULT).endswith(f"{zone[:3]}:{zone[3:]}")
    assert out.split("\n")[0].split()[0] == "time"
    # the status table lists the same fault on its own line, time read the same way
    _, out, _ = tvsctl(capsys, "status", "--socket", str(sock))
    assert local_time(T_FAULT) in out and "1.795e+09" not in out


def test_points_table_decodes_flags(serve: Any, capsys: pytest.CaptureFixture[str]) -> None:
    from tvsd.cli.daemon_cmds import _show_line

    _show_line({"x": 1.0, "flags": 6}, as_json=False)
    _show_line({"x": 1.0, "flags": 6}, as_json=True)
    human, raw = capsys.readouterr().out.splitlines()
    assert human == "x=1  flags=compensated+no_imu"
    assert json.loads(raw) == {"x": 1.0, "flags": 6}  # scripts keep the bits


DAEMON_COMMANDS = [
    ["status"],
    ["speed", "12.5"],
    ["scan", "start"],
    ["scan", "stop"],
    ["aim", "--phi-deg", "60", "--gamma-deg", "0"],
    ["aim", "--xyz", "0.3", "0.2", "0.05"],
    ["gains"],
    ["gains", "--set", "1,1,1,1"],
    ["record", "start"],
    ["record", "stop"],
    ["faults"],
    ["faults", "--clear"],
    ["calibrate-imu", "--seconds", "1"],
    ["shutdown"],
]


@pytest.mark.parametrize("argv", DAEMON_COMMANDS, ids=" ".join)
def test_every_json_is_one_object_never_wrapped(
    serve: Any, capsys: pytest.CaptureFixture[str], argv: list[str]
) -> None:
    """The JSON rule: one object, the answer itself; a list is named by the command."""
    sock = serve(Fake("fault", [FAULT]))
    status, out, err = tvsctl(capsys, *argv, "--json", "--socket", str(sock))
    assert (status, err) == (0, "")
    assert out.count("\n") == 1
    obj = json.loads(out)
    assert isinstance(obj, dict) and "result" not in obj, obj
    if argv == ["faults"]:
        assert obj == {"faults": [FAULT]}


def test_every_daemon_command_is_in_the_json_test() -> None:
    from tvsd.cli.main import _DAEMON_COMMANDS

    assert {a[0] for a in DAEMON_COMMANDS} == set(_DAEMON_COMMANDS) - {"points"}  # points: below


def test_points_on_a_faulted_drive_says_why_and_times_out(
    serve: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    """It used to hang silently. Bound: the timeout (2 s) + one state poll (1 s) + slack."""
    sock = serve(Fake("fault", [FAULT]))
    t0 = time.monotonic()
    status, out, err = tvsctl(capsys, "points", "--count", "1", "--timeout", "2", "--socket", str(sock))
    took = time.monotonic() - t0
    assert status == 1 and out == ""
    lines = err.splitlines()
    assert lines[0].startswith("tvsctl: waiting for points: the drive is faulted (MCU state frames stopped)")
    assert lines[-1].startswith("tvsctl: no point within 2 s: the drive is faulted")
    assert "faults --clear" in err
    assert 2.0 <= took < 8.0, took


def test_points_on_an_idle_daemon_names_the_fix(serve: Any, capsys: pytest.CaptureFixture[str]) -> None:
    sock = serve(Fake("idle"))
    status, _, err = tvsctl(capsys, "points", "--timeout", "1", "--socket", str(sock))
    assert status == 1 and "not scanning: `tvsctl speed 25` and `tvsctl scan start`" in err


def test_bench_prints_each_group_as_it_finishes_and_keeps_them_on_ctrl_c(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """It printed nothing for 20 minutes under load: now a group's figures are out before the
    next group starts, and Ctrl-C in a later group keeps them (exit 130)."""
    from tvsd.cli import bench

    seen: dict[str, str] = {}

    def second() -> dict[str, float]:
        seen["before_second"] = capsys.readouterr().out  # what the user saw while this one ran
        raise KeyboardInterrupt

    monkeypatch.setattr(bench, "BENCHES", {"first": lambda: {"first_figure": 1.5}, "second": second})
    status = cli.main(["bench"])
    err = capsys.readouterr().err
    assert status == 130
    assert "# first" in seen["before_second"] and "first_figure" in seen["before_second"]
    assert "interrupted in second" in err
    status = cli.main(["bench", "--json"])
    obj = json.loads(capsys.readouterr().out)
    assert status == 130 and obj["first_figure"] == 1.5 and obj["interrupted_in"] == "second"
    assert obj["groups_done"] == ["first"]


def _stderr_on_a_terminal(argv: list[str]) -> tuple[int, str, str]:
    """Run tvsctl with stderr on a pseudo-terminal (as a user's shell) and stdout piped."""
    import os
    import pty
    import subprocess
    import sys

    master, slave = pty.openpty()
    proc = subprocess.Popen(
        [sys.executable, "-m", "tvsd.cli.main", *argv], stdout=subprocess.PIPE, stderr=slave
    )
    os.close(slave)
    chunks = []
    while True:
        try:
            data = os.read(master, 65536)
        except OSError:  # EIO: the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    out = proc.stdout.read().decode() if proc.stdout else ""
    os.close(master)
    return proc.wait(60), out, b"".join(chunks).decode(errors="replace")


def test_long_work_shows_progress_on_a_terminal_and_none_when_piped(tmp_path: Path) -> None:
    """`export --format mcap` (as `sim scan`: tvsd.cli.progress) draws its bar on a terminal;
    piped, stderr stays empty and stdout has the result line only."""
    import subprocess
    import sys

    import numpy as np

    from tvsd.recording.writer import Recorder

    rec = tmp_path / "rec"
    with Recorder(rec, "plant: {}\n") as r:
        r.channel("loop", [("t", "<f8"), ("u", "<f8")]).append(
            {"t": np.arange(2000) / 1e3, "u": np.zeros(2000)}
        )
    argv = ["export", str(rec), "--format", "mcap", "--out", str(tmp_path / "r.mcap")]
    status, out, err = _stderr_on_a_terminal(argv)
    assert status == 0 and "MCAP, /tvsd/loop 2000 messages" in out, err
    assert "writing r.mcap" in err and "\x1b[" in err  # the bar (rich) on the terminal
    piped = subprocess.run(
        [sys.executable, "-m", "tvsd.cli.main", *argv], capture_output=True, text=True, timeout=300
    )
    assert piped.returncode == 0 and piped.stderr == "" and piped.stdout == out


def test_a_daemon_command_waits_at_most_its_timeout_and_says_for_what(
    serve: Any, capsys: pytest.CaptureFixture[str]
) -> None:
    """Bound: --timeout 1 s, plus the interpreter's slack on a loaded machine."""
    fake = Fake()
    fake.delay_s = 30.0
    sock = serve(fake)
    t0 = time.monotonic()
    status, _, err = tvsctl(capsys, "record", "stop", "--timeout", "1", "--socket", str(sock))
    assert status == 3 and "did not answer 'record_stop' within 1 s" in err, err
    assert time.monotonic() - t0 < 5.0
    status, _, err = tvsctl(capsys, "status", "--timeout", "0", "--socket", str(sock))
    assert status == 2 and "--timeout 0: give seconds > 0" in err


def test_every_command_prints_its_json_through_the_one_rule() -> None:
    """Statically, over every tvsctl module: a --json answer leaves only through print_json (one
    object, checked at run time); the one other JSON print is the points stream's line."""
    import ast

    import tvsd.cli as pkg

    offenders = []
    for path in sorted(Path(pkg.__file__).parent.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if (
                isinstance(node, ast.Call)
                and getattr(node.func, "id", None) == "print"
                and any("json.dumps" in ast.unparse(a) for a in node.args)
            ):
                offenders.append(f"{path.name}:{node.lineno}")
    assert [o.split(":")[0] for o in offenders] == ["daemon_cmds.py", "output.py"], offenders
    from tvsd.cli.output import print_json

    with pytest.raises(TypeError, match="one object"):
        print_json([1, 2])  # type: ignore[arg-type]
