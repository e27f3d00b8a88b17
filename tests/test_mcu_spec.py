"""protocol.yaml loading, validation and the command-table hash."""

from __future__ import annotations

import zlib
from pathlib import Path

import pytest

from tvsd.errors import ConfigError, ProtocolError
from tvsd.hw.mcu.spec import DEFAULT_SPEC_PATH, load_spec, parse_spec

P = Path("test.yaml")


def small_doc() -> dict:
    return {
        "version": 3,
        "sync": 0xA5,
        "max_payload": 8,
        "messages": [
            {"id": 0x81, "name": "pong", "dir": "m2h", "fields": [["a", "u8"], ["b", "i32"]]},
            {"id": 0x01, "name": "ping", "dir": "h2m", "fields": []},
        ],
    }


def test_default_spec_loads_and_is_consistent() -> None:
    spec = load_spec()
    assert spec.path == DEFAULT_SPEC_PATH.resolve()
    assert spec.sync == 0xA5 and spec.version == 2
    # Sizes the link code relies on (a change here must be a deliberate protocol change):
    # v2's 10 kHz pair is a 15-byte state frame and an 11-byte pwm_set.
    assert spec.by_name("state").size == 6
    assert spec.by_name("pwm_set").size == 2
    assert spec.by_name("heartbeat_ack").size == 8
    assert max(m.size for m in spec.messages) <= spec.max_payload
    ids = [m.id for m in spec.messages]
    assert len(ids) == len(set(ids))


def test_ack_statuses_come_from_the_spec() -> None:
    spec = load_spec()
    assert spec.ack_status[0][0] == "ok"
    assert spec.ack_meaning(3) == "the stepper axis is already moving"
    assert spec.ack_meaning(99) == "error code 99"


@pytest.mark.parametrize(
    "raw", [{1: ["bad", "x"]}, {0: "ok"}, {0: ["ok", "fine"], 1: ["not an id", "x"]}]
)
def test_bad_ack_status_is_refused(raw) -> None:
    doc = small_doc()
    doc["ack_status"] = raw
    with pytest.raises(ConfigError, match="ack_status"):
        parse_spec(doc, P)


def test_generator_and_host_share_the_parser(tmp_path: Path) -> None:
    """gen_protocol.py writes every constant from the parsed spec: the version, the frame
    layout, the hash and the ack statuses the host reads."""
    import subprocess
    import sys

    spec = load_spec()
    out = tmp_path / "protocol_gen.h"
    gen = Path(__file__).resolve().parents[1] / "firmware" / "gen_protocol.py"
    subprocess.run([sys.executable, str(gen), "--out", str(out)], check=True)
    text = out.read_text()
    assert f"#define PROTOCOL_VERSION {spec.version}u" in text
    assert f"#define PROTOCOL_TABLE_HASH 0x{spec.table_hash:08X}ul" in text
    assert "#define PROTO_OVERHEAD 9u" in text
    for code, (name, _) in spec.ack_status.items():
        assert f"#define ACK_{name.upper()} {code}u" in text


def test_yaml_on_is_a_field_name_not_a_boolean() -> None:
    # YAML 1.1 would read laser_set's field `on` as True; the spec loader uses YAML 1.2 booleans.
    assert load_spec().by_name("laser_set").field_names == ("on",)


def test_table_hash_is_crc32_of_the_canonical_text() -> None:
    spec = parse_spec(small_doc(), P)
    text = "1:ping:\n129:pong:a:u8,b:i32\n"  # sorted by id, decimal ids, empty field list
    assert spec.canonical_text == text
    assert spec.table_hash == zlib.crc32(text.encode())


def test_hash_changes_with_any_field() -> None:
    doc = small_doc()
    h0 = parse_spec(doc, P).table_hash
    doc["messages"][0]["fields"][1][1] = "u32"
    assert parse_spec(doc, P).table_hash != h0


@pytest.mark.parametrize(
    ("mutate", "needle"),
    [
        (lambda d: d["messages"].append(dict(d["messages"][0], name="x")), "used twice"),
        (lambda d: d["messages"][0].update(dir="h2m"), "outside the h2m range"),
        (lambda d: d["messages"][1].update(dir="sideways"), "dir must be"),
        (lambda d: d["messages"][0]["fields"].append(["c", "u32"]), "exceeds max_payload 8"),
        (lambda d: d["messages"][0]["fields"].append(["c", "f32"]), "type in"),
        (lambda d: d["messages"][0]["fields"].append(["a", "u8"]), "appears twice"),
        (lambda d: d.pop("sync"), "missing top-level key 'sync'"),
        (lambda d: d.update(max_payload=300), "max_payload must be"),
    ],
)
def test_bad_specs_are_refused_naming_the_file(mutate, needle) -> None:
    doc = small_doc()
    mutate(doc)
    with pytest.raises(ConfigError, match=needle) as info:
        parse_spec(doc, P)
    assert str(info.value).startswith("test.yaml")


def test_missing_file_says_where_it_belongs(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read the protocol spec"):
        load_spec(tmp_path / "nope.yaml")


def test_explicit_path(tmp_path: Path) -> None:
    f = tmp_path / "p.yaml"
    f.write_text(
        "version: 9\nsync: 0x55\nmax_payload: 4\n"
        'messages:\n  - {id: 0x02, name: go, dir: h2m, fields: [["on", u8]]}\n'
    )
    spec = load_spec(f)
    assert (spec.version, spec.sync, spec.by_name("go").field_names) == (9, 0x55, ("on",))


def test_a_bare_yaml_boolean_field_name_says_to_quote_it(tmp_path: Path) -> None:
    f = tmp_path / "p.yaml"
    f.write_text(
        "version: 9\nsync: 0x55\nmax_payload: 4\n"
        "messages:\n  - {id: 0x02, name: go, dir: h2m, fields: [[on, u8]]}\n"
    )
    with pytest.raises(ConfigError, match="quote such names"):
        load_spec(f)


def test_pack_checks_names_and_ranges() -> None:
    m = load_spec().by_name("pwm_set")
    assert m.unpack(m.pack({"duty": -32767})) == (-32767,)
    with pytest.raises(ProtocolError, match="does not fit i16"):
        m.pack({"duty": 40000})
    with pytest.raises(ProtocolError, match="takes fields"):
        m.pack({"dutty": 1})
    with pytest.raises(ProtocolError, match="needs 2 payload bytes"):
        m.unpack(b"\x00")
