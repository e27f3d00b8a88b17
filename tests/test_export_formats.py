"""`tvsctl export --format csv | parquet | mcap`, each read back with the format's own library, and
the README's numpy/pandas/mcap recipes run as they are written (issue 15 item 5)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from tvsd.cli.main import main
from tvsd.recording.writer import Recorder

README = Path(__file__).resolve().parents[1] / "README.md"
SECONDS, RATE = 2.0, 1000.0


@pytest.fixture(scope="module")
def rec(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A recording as the daemon writes one: loop (1 kHz), points (t_mono, flags), marks."""
    path = tmp_path_factory.mktemp("rec") / "rec-1"
    n = int(SECONDS * RATE)
    t = 100.0 + np.arange(n) / RATE  # the loop's clock does not start at 0
    with Recorder(path, "plant:\n  J: 6.4e-05\n") as r:
        loop = r.channel("loop", [("t", "<f8"), ("u", "<f8"), ("omega", "<f8"), ("phi", "<f8")])
        loop.append(
            {"t": t, "u": np.full(n, 5.9), "omega": 2 * np.pi * 25 + np.sin(t), "phi": 2 * np.pi * 25 * t}
        )
        pts = r.channel("points", [("x", "<f8"), ("flags", "<i8"), ("t_mono", "<f8")])
        pts.append(
            {"x": np.linspace(0.5, 0.6, 50), "flags": np.full(50, 2), "t_mono": 5000.0 + np.arange(50) * 0.04}
        )
        r.mark("state", state="scanning")
    return path


def export(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    code = main(["export", *argv])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert err == ""  # piped: no progress bar, no noise
    return out


def recipes() -> list[str]:
    section = README.read_text().split("### Recordings in other tools", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```python\n(.*?)```", section, re.S)


def test_readme_recipes_run(rec: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    paths = {"OUT": tmp_path / "r.csv", "PARQUET": tmp_path / "r.parquet", "MCAP": tmp_path / "r.mcap"}
    export(capsys, str(rec), "--csv", str(paths["OUT"]))
    export(capsys, str(rec), "--format", "parquet", "--out", str(paths["PARQUET"]))
    export(capsys, str(rec), "--format", "mcap", "--out", str(paths["MCAP"]))
    found = recipes()
    assert len(found) == 3, "the README's recipes (numpy, pandas, mcap)"
    for code in found:
        scope: dict[str, object] = {k: str(v) for k, v in paths.items()}
        exec(code, scope)  # the README as a user pastes it
    assert len(scope["loop"]) == SECONDS * RATE  # type: ignore[arg-type]


def test_the_old_numpy_recipe_fails_for_the_reason_the_readme_gives(
    rec: Path, tmp_path: Path, capsys
) -> None:
    out = tmp_path / "r.csv"
    export(capsys, str(rec), "--csv", str(out))
    with pytest.raises(ValueError, match=r"got \d+ columns instead of 1"):  # names from "# tvs-recording: 1"
        np.genfromtxt(out, delimiter=",", names=True, comments="#")


def test_parquet_reads_back_with_pyarrow_and_pandas(rec: Path, tmp_path: Path, capsys) -> None:
    import pandas
    import pyarrow.parquet as pq

    from tvsd.recording.csvfile import read

    csv, pqt = tmp_path / "r.csv", tmp_path / "r.parquet"
    export(capsys, str(rec), "--csv", str(csv))
    export(capsys, str(rec), "--format", "parquet", "--out", str(pqt))
    table = pq.read_table(pqt)
    meta = {k.decode(): v.decode() for k, v in table.schema.metadata.items()}
    assert meta["tvs-recording"] == "1" and meta["sample_rate_hz"] == "1000" and meta["plant.J"] == "6.4e-05"
    frame = pandas.read_parquet(pqt)
    ref = read(csv)
    assert list(frame.columns[:4]) == ["t", "u", "omega", "phi"]
    # Parquet keeps float64 exactly; the CSV keeps 9 significant digits.
    np.testing.assert_allclose(frame["omega"], ref.omega, rtol=1e-8)
    assert frame["t"].iloc[0] == 0.0 and frame["t"].iloc[-1] == pytest.approx(SECONDS - 1 / RATE)


def test_mcap_has_every_channel_with_a_json_schema(rec: Path, tmp_path: Path, capsys) -> None:
    from mcap.reader import make_reader

    out = tmp_path / "r.mcap"
    line = export(capsys, str(rec), "--format", "mcap", "--out", str(out))
    assert "/tvsd/loop 2000" in line and "/tvsd/points 50" in line and "/tvsd/marks" in line
    with out.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        topics = {c.topic: c for c in summary.channels.values()}
        assert {"/tvsd/loop", "/tvsd/points", "/tvsd/marks"} <= topics.keys()
        for ch in topics.values():
            schema = summary.schemas[ch.schema_id]
            assert ch.message_encoding == "json" and schema.encoding == "jsonschema"
            props = json.loads(schema.data)["properties"]
            assert props, ch.topic
        msgs = {}
        for schema, channel, message in reader.iter_messages():
            row = json.loads(message.data)
            assert set(json.loads(schema.data)["required"]) <= row.keys()  # each message fits its schema
            msgs.setdefault(channel.topic, []).append((message.log_time, row))
    loop = msgs["/tvsd/loop"]
    assert len(loop) == 2000 and loop[0][1]["t"] == 100.0
    assert (loop[1][0] - loop[0][0]) == 1_000_000  # 1 ms in ns: times kept within the channel
    assert msgs["/tvsd/points"][0][1]["flags"] == 2
    assert msgs["/tvsd/marks"][0][1]["event"] == "state"


def test_export_usage_errors_are_one_line(rec: Path, tmp_path: Path, capsys) -> None:
    for argv in (
        [str(rec)],
        [str(rec), "--csv", "a.csv", "--out", "b.csv"],
        [str(rec), "--csv", "a", "--format", "mcap"],
    ):
        assert main(["export", *argv]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "give --out OUT" in err
