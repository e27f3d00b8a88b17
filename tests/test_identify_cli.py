"""`tvsctl identify` against a fake daemon on a real socket (tests/test_client.py's way): the run's
progress is followed to its outcome, the end names the recording and the next command, an abort or
a timeout exits 1 with the reason (and a timeout aborts the run), bad arguments exit 2 without a
call. tests/test_identify_daemon.py runs it against the real daemon."""

from __future__ import annotations

import json
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tvsd.cli import main as cli
from tvsd.daemon.rpc import INVALID_PARAMS, RpcError, ThreadedRpcServer

REC = "/data/rec-20261126-080000"
EXC = {"kinds": ["steps", "prbs"], "seconds": 2.0, "peak_rps": 0.5, "peak_volts": 0.5}


class FakeIdentify:
    """identify / identify_status / identify_abort: `polls` statuses 'running', then `outcome`."""

    def __init__(self, outcome: str | None, polls: int = 3, reason: str = "") -> None:
        self.outcome, self.polls, self.reason = outcome, polls, reason
        self.calls: list[tuple[str, dict[str, Any]]] = []
        self.aborted = False

    def _status(self, n: int) -> dict[str, Any]:
        over = self.aborted or (self.outcome is not None and n >= self.polls)
        outcome = "aborted" if self.aborted else self.outcome
        return {
            "state": outcome if over else "running",
            "outcome": outcome if over else None,
            "reason": "aborted by request" if self.aborted else self.reason,
            "elapsed_s": min(2.0, n * 0.5),
            "seconds": 2.0,
            "progress": min(1.0, n / max(self.polls, 1)),
            "recording": REC,
            "rps_setpoint": 20.0,
            "excitation": EXC,
        }

    def table(self) -> dict[str, Any]:
        async def identify(seconds: float | None = None, kinds: list | None = None, seed: int | None = None):
            self.calls.append(("identify", {"seconds": seconds, "kinds": kinds, "seed": seed}))
            if seconds is not None and seconds > 100:
                raise RpcError(INVALID_PARAMS, "identify.seconds: must be at most max_seconds (120 s)")
            return self._status(0)

        async def identify_status():
            n = sum(1 for c in self.calls if c[0] == "identify_status")
            self.calls.append(("identify_status", {}))
            return self._status(n)

        async def identify_abort():
            self.calls.append(("identify_abort", {}))
            self.aborted = True
            return self._status(0)

        return {"identify": identify, "identify_status": identify_status, "identify_abort": identify_abort}


@pytest.fixture
def sock() -> Iterator[Path]:
    with tempfile.TemporaryDirectory() as tmp:
        yield Path(tmp) / "tvsd.sock"


def _serve(sock: Path, fake: FakeIdentify):
    return ThreadedRpcServer(sock, fake.table())


def test_a_run_is_followed_to_done_and_names_the_next_command(sock, capsys):
    fake = FakeIdentify("done")
    with _serve(sock, fake):
        rc = cli.main(
            ["identify", "--socket", str(sock), "--seconds", "2", "--kinds", "steps,prbs", "--json"]
        )
    out = capsys.readouterr()
    assert rc == 0, out.err
    res = json.loads(out.out)
    assert res["outcome"] == "done"
    assert (
        res["next"]
        == f"tvsctl export {REC} --csv rec-20261126-080000.csv && tvsctl analyze rec-20261126-080000.csv"
    )
    assert fake.calls[0] == ("identify", {"seconds": 2.0, "kinds": ["steps", "prbs"], "seed": None})
    assert "identify: steps, prbs for 2 s on top of 20 rev/s" in out.err
    assert "%" in out.err  # progress lines while it ran


def test_an_aborted_run_exits_1_with_its_reason(sock, capsys):
    fake = FakeIdentify("aborted", reason="fault: MCU link lost: no frame for 50 ms")
    with _serve(sock, fake):
        rc = cli.main(["identify", "--socket", str(sock)])
    err = capsys.readouterr().err
    assert rc == 1
    assert f"identify aborted: fault: MCU link lost: no frame for 50 ms; the recording so far: {REC}" in err


def test_a_timeout_aborts_the_run(sock, capsys):
    fake = FakeIdentify(None)  # never ends by itself
    with _serve(sock, fake):
        rc = cli.main(["identify", "--socket", str(sock), "--timeout", "0.6"])
    err = capsys.readouterr().err
    assert rc == 1 and "no outcome within --timeout 0.6 s" in err
    assert ("identify_abort", {}) in fake.calls


@pytest.mark.parametrize(
    "argv,expect",
    [
        (["--kinds", "steps,chirp"], "--kinds 'steps,chirp': give any of steps,multisine,prbs"),
        (["--seconds", "-3"], "--seconds -3: give a positive duration"),
        (["--timeout", "0"], "--timeout 0: give a positive number of seconds"),
        (["--seconds", "500"], "identify.seconds: must be at most max_seconds (120 s)"),
    ],
)
def test_bad_arguments_exit_2(sock, capsys, argv, expect):
    fake = FakeIdentify("done")
    with _serve(sock, fake):
        rc = cli.main(["identify", "--socket", str(sock), *argv])
    assert rc == 2
    assert expect in capsys.readouterr().err
    assert all(c[0] == "identify" for c in fake.calls)  # refused before any run started


def test_no_daemon_exits_3(sock, capsys):
    assert cli.main(["identify", "--socket", str(sock)]) == 3
