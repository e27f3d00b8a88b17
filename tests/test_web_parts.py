"""The live view's parts without a server: the report paths it may serve, the bounded series each
browser reads from its cursor, the IMU spectra and their shaft orders, the `web:` config section."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from conftest import replace_section

from tvsd.config import WebSettings, load_config
from tvsd.daemon.web.feed import Cursor, LiveFeed, decode_points, encode
from tvsd.daemon.web.reports import find_reports, resolve
from tvsd.daemon.web.spectra import ImuWindow
from tvsd.errors import ConfigError, UsageError
from tvsd.scan.points import Point

CONFIG_DIR = Path(__file__).resolve().parent.parent / "config"


@pytest.fixture
def data_dir(tmp_path: Path) -> Path:
    data = tmp_path / "data"
    rep = data / "doctor-emps" / "report.md"
    rep.parent.mkdir(parents=True)
    rep.write_text("# Model doctor: emps\n\n![fit](fit.png)\n")
    (rep.parent / "fit.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    (rep.parent / "notes.py").write_text("x = 1\n")
    (data / "rec-20260101-000000").mkdir()
    (data / "rec-20260101-000000" / "meta.json").write_text("{}")  # a recording, not a report
    (data / "imu-calibration-sil.json").write_text("{}")
    (tmp_path / "secret.md").write_text("outside")
    (rep.parent / "link-out.md").symlink_to(tmp_path / "secret.md")
    return data


def test_reports_are_listed_and_only_their_files_are_served(data_dir: Path):
    reports = find_reports(data_dir)
    assert [r["path"] for r in reports] == ["doctor-emps/report.md"]
    assert reports[0]["title"] == "Model doctor: emps"
    assert resolve(data_dir, "doctor-emps/report.md") == (data_dir / "doctor-emps/report.md").resolve()
    assert resolve(data_dir, "doctor-emps/fit.png") is not None
    for bad in (
        "../secret.md",  # out of the data dir
        "doctor-emps/../../secret.md",
        "/etc/passwd",
        "doctor-emps/link-out.md",  # a link out of the data dir
        "doctor-emps/notes.py",  # not a kind of file a report has
        "rec-20260101-000000/meta.json",  # not in a report folder
        "imu-calibration-sil.json",  # the data dir itself is not a report folder
        "doctor-emps\\report.md",
        "doctor-emps/./report.md",
        "",
        "doctor-emps/missing.png",
    ):
        assert resolve(data_dir, bad) is None, bad


def test_a_report_md_in_the_data_dir_itself_does_not_open_the_data_dir(data_dir: Path):
    (data_dir / "report.md").write_text("# planted\n")
    assert resolve(data_dir, "imu-calibration-sil.json") is None
    assert [r["path"] for r in find_reports(data_dir)] == ["doctor-emps/report.md"]


def _status(t: int, rps: float) -> dict:
    return {
        "state": "scanning",
        "rps": rps,
        "rps_setpoint": 25.0,
        "loop": {"ticks": 10000 * t, "missed_ticks": t, "jitter_p99_us": math.nan, "jitter_max_us": 80.0},
        "faults": [],
    }


def _point(x: float) -> Point:
    values = dict.fromkeys(Point.__dataclass_fields__, 0.0)
    values.update(x=x, y=1.0, z=0.1, sigma_x=3e-4, sigma_y=4e-4, sigma_z=0.0, flags=2)
    return Point(**values)


def test_a_browser_that_skipped_frames_gets_what_it_missed_and_nothing_grows():
    feed = LiveFeed(history_s=10, push_hz=5, cloud_points=100)
    fresh, slow = Cursor(), Cursor()
    feed.frame(fresh, hello=True)
    feed.frame(slow, hello=True)
    for t in range(3):
        feed.sample(_status(t, 20.0 + t), now=1000.0 + t)
        feed.point(_point(float(t)))
        assert len(feed.frame(fresh)["samples"]) == 1
    missed = feed.frame(slow)
    assert [row[1] for row in missed["samples"]] == [20.0, 21.0, 22.0]
    assert missed["samples"][0][3] is None  # a NaN p99 (no tick yet) is null, not NaN, in JSON
    pts = decode_points(missed["points"])
    assert pts[:, 0].tolist() == [0.0, 1.0, 2.0] and pts[:, 4].tolist() == [2, 2, 2]  # x, flags
    assert abs(pts[0, 3] - 0.5) < 1e-6  # σ in mm: √(0.3² + 0.4²)
    assert feed.frame(slow)["samples"] == []  # the cursor moved
    for t in range(3, 500):  # far more than is kept: the series stay bounded
        feed.sample(_status(t, 25.0), now=1000.0 + t)
        feed.point(_point(float(t)))
    assert len(feed.frame(slow)["samples"]) == 50  # 10 s at 5 Hz
    assert len(decode_points(feed.frame(Cursor(), hello=True)["points"])) == 100


def test_a_frame_splices_its_encoded_spectra_in_once():
    feed = LiveFeed(history_s=10, push_hz=5, cloud_points=100)
    feed.sample(_status(1, 25.0))
    feed.set_spectra('{"f":[0.0,2.0],"orders":[25.0]}')
    cur = Cursor()
    first = json.loads(encode(feed.frame(cur, hello=True)))
    assert first["spectra"]["orders"] == [25.0] and first["status"]["state"] == "scanning"
    assert "spectra" not in json.loads(encode(feed.frame(cur)))


def test_faults_are_sent_when_they_change_only():
    feed = LiveFeed(history_s=10, push_hz=5, cloud_points=100)
    cur = Cursor()
    feed.sample(_status(1, 25.0))
    assert feed.frame(cur, hello=True)["faults"] == []
    assert "faults" not in feed.frame(cur)
    fault = {"t_unix": 1.8e9, "cause": "control loop overran", "action": "PWM 0", "kind": "control_overrun"}
    feed.sample({**_status(2, 0.0), "faults": [fault]})
    assert feed.frame(cur)["faults"] == [fault]
    assert "faults" not in feed.frame(cur)


def test_spectra_show_a_shaft_line_at_its_order_and_mark_the_orders():
    """A 50 Hz line (2nd order at 25 rev/s) in the SA gyro x over white noise: the Welch PSD's peak
    above 10 Hz is within one bin (≈ 2 Hz) of 50 Hz, and the orders are k·25 Hz below Nyquist."""
    rate = 1000.0
    win = ImuWindow(rate, 4.0)
    rng = np.random.default_rng(1)
    t = np.arange(4000) / rate
    gyro = 0.01 * rng.standard_normal((4000, 3))
    gyro[:, 0] += 0.05 * np.sin(2 * np.pi * 50.0 * t)
    accel = rng.standard_normal((4000, 3))
    for k in range(0, 4000, 20):  # the reader's batches: 20 ms each
        win.push("sa", gyro[k : k + 20], accel[k : k + 20])
    assert win.spectra(25.0) is not None
    sp = win.spectra(25.0)
    f = np.asarray(sp["f"])
    gx = np.asarray(sp["psd_db"]["sa"]["gx"])
    band = f > 10
    assert abs(f[band][np.argmax(gx[band])] - 50.0) <= f[1]
    assert "pl" not in sp["psd_db"]  # no PL samples: nothing drawn for it
    assert sp["orders"] == [25.0 * k for k in range(1, 11)]  # ten orders, all below 500 Hz
    assert win.spectra(0.0)["orders"] == []  # standing still: no shaft line to mark


def test_the_imu_window_keeps_the_newest_samples_in_order():
    win = ImuWindow(100.0, 1.0)  # 100 samples
    for k in range(0, 250, 30):
        rows = np.arange(k, min(k + 30, 250), dtype=float)[:, None].repeat(3, axis=1)
        win.push("pl", rows, rows)
    assert win.samples("pl")[:, 0].tolist() == list(range(150, 250))


def _config_with(tmp_path: Path, web: str) -> Path:
    text = (CONFIG_DIR / "tvsd.yaml").read_text()
    text = text.replace("sil_profile: sil.yaml", f"sil_profile: {CONFIG_DIR / 'sil.yaml'}")
    path = tmp_path / "tvsd.yaml"
    path.write_text(replace_section(text, "web", web))
    return path


def test_the_web_section_is_off_by_default_and_checked_with_file_and_line(tmp_path: Path):
    assert load_config().web == WebSettings()
    assert not WebSettings().enabled and WebSettings().host == "127.0.0.1"
    cfg = load_config(_config_with(tmp_path, "  enabled: true\n  socket: /run/tvsd/web.sock\n"))
    assert cfg.web.enabled and cfg.web.socket == Path("/run/tvsd/web.sock")
    for web, problem in (
        ("  enabled: true\n  port: 70000\n", "web.port: must be at most 65535"),
        ("  enabled: true\n  push_hz: 20\n", "web.push_hz: must be at most 5"),
        ("  enabled: true\n  socket: web.sock\n", "web.socket: web.sock is relative"),
        ("  enabled: true\n  socket: /" + "x" * 120 + "\n", "longer than 107 bytes"),
        ("  enable: true\n", "did you mean 'enabled'"),
        ("  floor_every_s: 5\n", "web.floor_every_s: 5 s would measure"),
    ):
        path = _config_with(tmp_path, web)
        with pytest.raises(ConfigError, match=problem) as err:
            load_config(path)
        line = int(str(err.value).split(":")[1])
        lines = path.read_text().splitlines()
        first = lines.index("web:") + 1  # 1-based: the error names a line of the web section
        assert first <= line <= first + web.count("\n"), str(err.value)
    with pytest.raises(UsageError):
        WebSettings(push_hz=6)
    assert os.sep == "/"
