"""A SIL daemon against hostile and unlucky requests (issue 13 items 3 and 4), over its real socket.

Every case here failed before issue 13: a 400-digit integer to speed/aim/gains_set was a -32603
internal error; ``"id": 1e999`` got "reply is not JSON"; a batch of 300 `status` calls ran at once
(the loop stalled 1.8 s); record start/stop/start within a second was refused (the same
rec-… name); a symlink planted under the next rec-… name made record_start write outside the
data directory; `status.rps` read 25 rev/s 1.5 s after the link was lost, unmarked; and
`tvsd --socket /nonexistent/dir/x.sock` created the directory.
No timing is asserted: waits are bounded generously and only outcomes are checked.
"""

from __future__ import annotations

import contextlib
import json
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import wait_for

pytestmark = pytest.mark.slow  # one SIL daemon for the module: ≈ 10–30 s on a loaded 2-core machine

START_S = 60.0


class Client:
    """One connection to the daemon, line by line."""

    def __init__(self, sock: Path) -> None:
        self.s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.s.connect(str(sock))
        self.s.settimeout(20)
        self.f = self.s.makefile("rwb")

    def line(self, raw: bytes) -> object:
        self.f.write(raw + b"\n")
        self.f.flush()
        return json.loads(self.f.readline())

    def call(self, method: str, **params: object) -> dict:
        reply = self.line(
            json.dumps({"jsonrpc": "2.0", "id": 1, "method": method, "params": params}).encode()
        )
        assert isinstance(reply, dict)
        return reply

    def close(self) -> None:
        self.s.close()


@pytest.fixture(scope="module")
def sil(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, Path, Path]]:
    tmp = tmp_path_factory.mktemp("bounds")
    sock, data, log = tmp / "run" / "tvsd.sock", tmp / "data", tmp / "tvsd.log"
    with log.open("w") as out:
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "tvsd.daemon.main",
                "--sil",
                "--socket",
                str(sock),
                "--data-dir",
                str(data),
            ],
            stdout=out,
            stderr=out,
        )
    try:
        wait_for(
            lambda: sock.exists() or proc.poll() is not None, START_S, "the daemon's socket", interval=0.2
        )
        assert proc.poll() is None, log.read_text()
        c = Client(sock)
        wait_for(
            lambda: c.call("status")["result"]["state"] != "starting", START_S, "devices up", interval=0.2
        )
        c.close()
        yield sock, data, tmp
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(10)
        print("tvsd's log (its tail):\n" + "".join(log.read_text().splitlines(keepends=True)[-30:]))


@pytest.fixture
def client(sil: tuple[Path, Path, Path]) -> Iterator[Client]:
    c = Client(sil[0])
    yield c
    c.close()


HUGE = "9" * 400


def _raw(method: str, params: str) -> str:
    return '{"jsonrpc":"2.0","id":1,"method":"' + method + '","params":' + params + "}"


@pytest.mark.parametrize(
    "raw",
    [
        _raw("speed", '{"rps":' + HUGE + "}"),
        _raw("aim", '{"phi_deg":' + HUGE + ',"gamma_deg":0}'),
        _raw("gains_set", '{"Gp":' + HUGE + ',"Gd":1,"Gr":1,"G0":1}'),
        _raw("gains_set", '{"Gp":1e30,"Gd":1,"Gr":1,"G0":1}'),
        _raw("record_window", '{"seconds":1e999}'),
        _raw("imu_calibrate", '{"seconds":-' + HUGE + "}"),
    ],
)
def test_out_of_range_numbers_are_a_clear_invalid_params(client: Client, raw: str) -> None:
    reply = client.line(raw.encode())
    assert isinstance(reply, dict) and reply["error"]["code"] == -32602, reply
    assert len(reply["error"]["message"]) < 300 and "\n" not in reply["error"]["message"]


def test_an_infinite_id_is_an_invalid_request(client: Client) -> None:
    reply = client.line(b'{"jsonrpc":"2.0","id":1e999,"method":"status"}')
    assert isinstance(reply, dict) and reply["error"]["code"] == -32600 and reply["id"] is None, reply
    assert "result" in client.call("status")  # the connection lives on


def test_subscribing_to_a_topic_the_daemon_never_publishes_is_invalid_params(client: Client) -> None:
    """`subscribe {"topic": "nope"}` answered {"subscribed": true} (a typo waits for ever); now a
    -32602 naming the daemon's topics (tvsd.daemon.app.TOPICS)."""
    reply = client.call("subscribe", topic="piont")
    assert reply["error"]["code"] == -32602, reply
    assert "status" in reply["error"]["message"] and "points" in reply["error"]["message"]
    assert client.call("subscribe", topic="faults")["result"] == {"topic": "faults", "subscribed": True}
    assert client.call("unsubscribe", topic="faults")["result"]["subscribed"] is False


def test_a_batch_of_300_status_calls_is_refused_and_50_are_answered(client: Client) -> None:
    batch = [{"jsonrpc": "2.0", "id": k, "method": "status"} for k in range(300)]
    reply = client.line(json.dumps(batch).encode())
    assert isinstance(reply, dict) and reply["error"]["code"] == -32003, str(reply)[:300]
    assert reply["error"]["data"] == {"limit": "max_batch", "value": 50, "seen": 300}
    replies = client.line(json.dumps(batch[:50]).encode())
    assert isinstance(replies, list) and [r["id"] for r in replies] == list(range(50))
    assert sum(len(json.dumps(r)) for r in replies) < 1 << 20


def test_record_start_stop_start_within_a_second_gives_distinct_recordings(
    client: Client, sil: tuple[Path, Path, Path]
) -> None:
    paths = []
    for _ in range(3):
        started = client.call("record_start")
        assert "result" in started, started
        paths.append(Path(started["result"]["recording"]))
        assert client.call("record_stop")["result"]["recorded"] == str(paths[-1])
    assert len(set(paths)) == 3 and all(p.parent == sil[1] and p.is_dir() for p in paths), paths


def test_a_symlink_planted_under_the_next_name_is_not_followed(
    client: Client, sil: tuple[Path, Path, Path]
) -> None:
    _, data, tmp = sil
    outside = tmp / "outside"
    outside.mkdir()
    now = time.time()
    planted = []
    for dt in range(-1, 30):  # every name record_start could pick in the next 30 s
        name = data / time.strftime("rec-%Y%m%d-%H%M%S", time.localtime(now + dt))
        if not name.exists() and not name.is_symlink():
            name.symlink_to(outside)
            planted.append(name)
    started = client.call("record_start")
    assert "result" in started, started
    path = Path(started["result"]["recording"])
    client.call("record_stop")
    assert path.parent == data and not path.is_symlink() and path.is_dir()
    assert list(outside.iterdir()) == [], "the recording went through the planted link"
    for name in planted:
        name.unlink()


def test_status_is_marked_stale_once_the_link_is_lost(client: Client) -> None:
    """Before: `rps` still read 25 rev/s 1.5 s after the loss, with nothing to say it was old.
    Now `stale` turns true once the newest measurement is older than daemon.stale_after_ms."""
    s = client.call("status")["result"]
    assert s["stale"] is False and s["measurement_age_ms"] < 1000, s
    assert "result" in client.call("inject_fault", device="mcu", fault="link_loss")
    try:
        s = wait_for(
            lambda: client.call("status")["result"], 20.0, "status marked stale", ok=lambda s: s["stale"]
        )
        assert s["measurement_age_ms"] > 100
        # the link's own report comes at mcu.link_lost_ms (500 ms: the late-input hold's bound)
        lost = lambda s: s["link"]["state"] == "lost"  # noqa: E731
        wait_for(lambda: client.call("status")["result"], 20.0, "the link's loss", ok=lost)
    finally:
        client.call("inject_fault", device="mcu", fault="link_restore")
    wait_for(lambda: client.call("status")["result"], 30.0, "fresh again", ok=lambda s: not s["stale"])
    client.call("faults_clear")
    s = client.call("status")["result"]
    assert len(s["faults"]) <= 10 and sum(s["fault_counts"].values()) >= 1


def test_a_socket_in_a_missing_directory_is_refused_not_created(tmp_path: Path) -> None:
    missing = tmp_path / "nonexistent" / "dir"
    proc = subprocess.run(
        [sys.executable, "-m", "tvsd.daemon.main", "--sil", "--socket", str(missing / "x.sock"),
         "--data-dir", str(tmp_path / "data")],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert lines[-1].startswith("tvsd: --socket") and "does not exist" in lines[-1], lines
    assert not missing.parent.exists()


def test_imu_calibration_succeeds_at_rest_in_sil(client: Client, sil: tuple[Path, Path, Path]) -> None:
    """Before: "pl IMU is moving" at 0 rev/s, always (tests/test_imu_sil_rest.py says why). The
    file goes beside the SIL daemon's data (tvsd --sil: DATA_DIR/imu-calibration-sil.json)."""
    from tvsd.hw.imu_calibration import SIL_FILE_NAME

    wait_for(
        lambda: client.call("status")["result"]["imu"]["state"], 30.0, "the IMUs up", ok=lambda s: s == "ok"
    )
    # A starved SIL (the twins follow the plant's pace) can deliver under half the samples of a
    # second on this loaded machine: that refusal is retried; "is moving" never is.
    for _ in range(5):
        reply = client.call("imu_calibrate", seconds=2.0)
        if "result" in reply or "samples in" not in reply["error"]["message"]:
            break
    else:  # the motion check never ran; tests/test_imu_sil_rest.py covers it without the pace
        pytest.skip(f"SIL IMU starved by the machine's load: {reply['error']['message'][:90]}")
    assert "result" in reply, reply
    assert reply["result"]["file"] == str(sil[1] / SIL_FILE_NAME)
    assert (sil[1] / SIL_FILE_NAME).is_file()


def test_the_status_carries_only_the_newest_faults(client: Client) -> None:
    """Before: every listed fault rode in every status (1.7 → 45 KB in 3 min of watchdog faults).
    Now the newest daemon.status_faults (10); faults_list has the ring (200), fault_counts all."""
    client.call("faults_clear")

    def imu_faults() -> int:
        return int(client.call("status")["result"]["fault_counts"].get("imu", 0))

    def imu_state() -> str:
        return str(client.call("status")["result"]["imu"]["state"])

    listed: list[dict] = []
    for _ in range(30):  # a fault per change of state: back to ok before each loss
        if len(listed) >= 12:
            break
        wait_for(imu_state, 30.0, "the IMUs ok", ok=lambda st: st == "ok")
        before = imu_faults()
        assert "result" in client.call("inject_fault", device="imu", fault="loss")
        with contextlib.suppress(AssertionError):  # a loss the loaded machine hid: one more round
            wait_for(imu_faults, 10.0, "an IMU loss fault", ok=lambda n, b=before: n > b)
        client.call("inject_fault", device="imu", fault="restore")
        listed = client.call("faults_list")["result"]
    s = client.call("status")["result"]
    listed = client.call("faults_list")["result"]
    assert len(listed) >= 12 and len(s["faults"]) == 10
    assert all(f in listed for f in s["faults"])  # the newest (a fault may land between the calls)
    assert s["faults"][0]["t_unix"] >= listed[-11]["t_unix"]
