"""The wire protocol, loaded from firmware/protocol.yaml (the single source of truth).

This module holds the one parser of that file: the firmware's C header is generated with it
(firmware/gen_protocol.py imports ``parse_spec``), and the host builds from it one ``MessageSpec``
(id, name, direction, fields and a ``struct.Struct``) per message, the ack statuses, and the
command-table hash that the MCU reports in its ``identify`` frame, exactly as the YAML header
defines it. It needs only the standard library, PyYAML and tvsd.errors, so the generator can run
in a bare build environment.

Where the file is: in a source checkout, ``firmware/protocol.yaml``; in an installed wheel, the
copy the build put beside this module (``tvsd/hw/mcu/protocol.yaml``, see setup.py).
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import yaml

from tvsd.errors import ConfigError, ProtocolError

# <repo>/firmware/protocol.yaml, seen from <repo>/tvsd/hw/mcu/spec.py (a source checkout)
CHECKOUT_SPEC_PATH = Path(__file__).resolve().parents[3] / "firmware" / "protocol.yaml"
# the copy setup.py's build step ships in the wheel
PACKAGED_SPEC_PATH = Path(__file__).resolve().parent / "protocol.yaml"
# The checkout's file wins when there is one: a stale packaged copy must never shadow it.
DEFAULT_SPEC_PATH = CHECKOUT_SPEC_PATH if CHECKOUT_SPEC_PATH.exists() else PACKAGED_SPEC_PATH

# protocol type -> (struct code, min, max)
TYPES: dict[str, tuple[str, int, int]] = {
    "u8": ("B", 0, 0xFF),
    "i8": ("b", -0x80, 0x7F),
    "u16": ("H", 0, 0xFFFF),
    "i16": ("h", -0x8000, 0x7FFF),
    "u32": ("I", 0, 0xFFFF_FFFF),
    "i32": ("i", -0x8000_0000, 0x7FFF_FFFF),
}
H2M, M2H = "h2m", "m2h"
# id ranges by direction, as the YAML comments state them
ID_RANGES = {H2M: range(0x01, 0x80), M2H: range(0x80, 0x100)}
# Frame v2: SYNC u8 | LEN u8 | SEQ u16 | ID u8 | PAYLOAD | CRC32 u32 (protocol.yaml header)
FRAME_HEADER = 5  # SYNC, LEN, SEQ (2), ID
FRAME_CRC = 4  # CRC-32 over SYNC..PAYLOAD
FRAME_OVERHEAD = FRAME_HEADER + FRAME_CRC
SEQ_MODULO = 0x1_0000
# The firmware's control tick (firmware/core/core_config.h CORE_TICK_HZ): it samples the encoder,
# and `state_div` counts these ticks between state frames.
CONTROL_TICK_HZ = 10_000


@dataclass(frozen=True)
class Field:
    name: str
    type: str


@dataclass(frozen=True)
class MessageSpec:
    id: int
    name: str
    dir: str
    fields: tuple[Field, ...]
    codec: struct.Struct

    @property
    def size(self) -> int:
        """Payload bytes."""
        return self.codec.size

    @property
    def field_names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.fields)

    def pack(self, values: Mapping[str, int]) -> bytes:
        """Payload bytes of this message; a missing, extra or out-of-range field is refused."""
        names = self.field_names
        if set(values) != set(names):
            raise ProtocolError(f"message {self.name} takes fields {list(names)}, got {sorted(values)}")
        for f in self.fields:
            v = values[f.name]
            _, lo, hi = TYPES[f.type]
            if not isinstance(v, int) or not lo <= v <= hi:
                raise ProtocolError(
                    f"message {self.name}: {f.name} = {v!r} does not fit {f.type} [{lo}, {hi}]"
                )
        return self.codec.pack(*(values[n] for n in names))

    def unpack(self, payload: bytes) -> tuple[int, ...]:
        if len(payload) != self.size:
            raise ProtocolError(f"message {self.name} needs {self.size} payload bytes, got {len(payload)}")
        return self.codec.unpack(payload)


@dataclass(frozen=True)
class ProtocolSpec:
    version: int
    sync: int
    max_payload: int
    messages: tuple[MessageSpec, ...]
    fault_codes: Mapping[int, str]
    pulse_channels: Mapping[int, str]
    boards: Mapping[int, str]
    ack_status: Mapping[int, tuple[str, str]]  # status -> (name, meaning)
    path: Path

    def by_name(self, name: str) -> MessageSpec:
        for m in self.messages:
            if m.name == name:
                return m
        raise ProtocolError(f"{self.path}: no message named {name!r}")

    def by_id(self, msg_id: int) -> MessageSpec | None:
        for m in self.messages:
            if m.id == msg_id:
                return m
        return None

    def payload_sizes(self, direction: str) -> dict[int, int]:
        """id -> payload size of the messages a receiver in ``direction`` may see."""
        return {m.id: m.size for m in self.messages if m.dir == direction}

    def max_frame(self) -> int:
        return self.max_payload + FRAME_OVERHEAD

    def ack_meaning(self, status: int) -> str:
        entry = self.ack_status.get(status)
        return entry[1] if entry is not None else f"error code {status}"

    @property
    def canonical_text(self) -> str:
        return canonical_text(self.messages)

    @property
    def table_hash(self) -> int:
        return zlib.crc32(self.canonical_text.encode("ascii")) & 0xFFFF_FFFF


def canonical_text(messages: tuple[MessageSpec, ...]) -> str:
    """One line per message sorted by id: "<id>:<name>:<field>:<type>,...\\n".

    The id is written in decimal (the YAML writes it in hex, but YAML hands over an integer and
    the header does not say otherwise; see firmware/protocol.yaml header).
    """
    lines = []
    for m in sorted(messages, key=lambda m: m.id):
        fields = ",".join(f"{f.name}:{f.type}" for f in m.fields)
        lines.append(f"{m.id}:{m.name}:{fields}\n")
    return "".join(lines)


def _int_map(raw: Any, key: str, path: Path) -> dict[int, str]:
    if raw is None:
        return {}
    if not isinstance(raw, dict) or not all(isinstance(k, int) for k in raw):
        raise ConfigError(f"{path}: '{key}' must map integers to names")
    return {int(k): str(v) for k, v in raw.items()}


def _ack_map(raw: Any, path: Path) -> dict[int, tuple[str, str]]:
    if raw is None:
        return {}
    ok = isinstance(raw, dict) and all(
        isinstance(k, int) and 0 <= k <= 0xFF and isinstance(v, list) and len(v) == 2
        and isinstance(v[0], str) and v[0].isidentifier() and isinstance(v[1], str)
        for k, v in raw.items()
    )
    if not ok:
        raise ConfigError(f"{path}: 'ack_status' must map 0..255 to [name, meaning]")
    out = {int(k): (str(v[0]), str(v[1])) for k, v in raw.items()}
    if out.get(0, ("",))[0] != "ok":
        raise ConfigError(f"{path}: ack_status 0 must be [ok, ...]: the firmware acks success with 0")
    return out


def parse_spec(doc: Any, path: Path) -> ProtocolSpec:
    """Validate a loaded protocol document and build the spec; every problem names the file."""
    if not isinstance(doc, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level")
    for key in ("version", "sync", "max_payload", "messages"):
        if key not in doc:
            raise ConfigError(f"{path}: missing top-level key '{key}'")
    version, sync, max_payload = doc["version"], doc["sync"], doc["max_payload"]
    if not isinstance(version, int) or not 0 <= version <= 0xFFFF:
        raise ConfigError(f"{path}: version must be an integer 0..65535, got {version!r}")
    if not isinstance(sync, int) or not 0 <= sync <= 0xFF:
        raise ConfigError(f"{path}: sync must be one byte, got {sync!r}")
    # LEN is one byte on the wire, and the C parser indexes its buffer with a byte
    if not isinstance(max_payload, int) or not 0 < max_payload <= 0xFF - FRAME_OVERHEAD:
        raise ConfigError(f"{path}: max_payload must be 1..{0xFF - FRAME_OVERHEAD}, got {max_payload!r}")
    raw_msgs = doc["messages"]
    if not isinstance(raw_msgs, list) or not raw_msgs:
        raise ConfigError(f"{path}: 'messages' must be a non-empty list")

    messages: list[MessageSpec] = []
    seen_ids: set[int] = set()
    seen_names: set[str] = set()
    for i, raw in enumerate(raw_msgs):
        where = f"{path}: messages[{i}]"
        if not isinstance(raw, dict) or set(raw) != {"id", "name", "dir", "fields"}:
            raise ConfigError(f"{where}: expected keys id, name, dir, fields; got {raw!r}")
        msg_id, name, direction, raw_fields = raw["id"], raw["name"], raw["dir"], raw["fields"]
        if not isinstance(name, str) or not name.isidentifier():
            raise ConfigError(f"{where}: name must be an identifier, got {name!r}")
        where = f"{path}: message {name}"
        if direction not in ID_RANGES:
            raise ConfigError(f"{where}: dir must be h2m or m2h, got {direction!r}")
        if not isinstance(msg_id, int) or msg_id not in ID_RANGES[direction]:
            r = ID_RANGES[direction]
            raise ConfigError(
                f"{where}: id {msg_id!r} is outside the {direction} range 0x{r.start:02X}..0x{r.stop - 1:02X}"
            )
        if msg_id in seen_ids:
            raise ConfigError(f"{where}: id 0x{msg_id:02X} is used twice")
        if name in seen_names:
            raise ConfigError(f"{where}: name is used twice")
        seen_ids.add(msg_id)
        seen_names.add(name)
        if not isinstance(raw_fields, list):
            raise ConfigError(f"{where}: fields must be a list of [name, type]")
        fields: list[Field] = []
        for rf in raw_fields:
            if not isinstance(rf, list) or len(rf) != 2 or not isinstance(rf[0], str) or rf[1] not in TYPES:
                raise ConfigError(
                    f"{where}: field {rf!r} must be [name, type] with type in {sorted(TYPES)} "
                    "(YAML reads a bare on/off/yes/no as a boolean: quote such names)"
                )
            if any(f.name == rf[0] for f in fields):
                raise ConfigError(f"{where}: field {rf[0]} appears twice")
            fields.append(Field(rf[0], rf[1]))
        codec = struct.Struct("<" + "".join(TYPES[f.type][0] for f in fields))
        if codec.size > max_payload:
            raise ConfigError(f"{where}: payload of {codec.size} bytes exceeds max_payload {max_payload}")
        messages.append(MessageSpec(msg_id, name, direction, tuple(fields), codec))

    return ProtocolSpec(
        version=version,
        sync=sync,
        max_payload=max_payload,
        messages=tuple(messages),
        fault_codes=_int_map(doc.get("fault_codes"), "fault_codes", path),
        pulse_channels=_int_map(doc.get("pulse_channels"), "pulse_channels", path),
        boards=_int_map(doc.get("boards"), "boards", path),
        ack_status=_ack_map(doc.get("ack_status"), path),
        path=path,
    )


def load_spec(path: str | Path | None = None) -> ProtocolSpec:
    """Load and validate protocol.yaml (default: the checkout's, else the one shipped in the wheel)."""
    p = Path(path) if path is not None else DEFAULT_SPEC_PATH
    return _load_cached(p.resolve())


@cache
def _load_cached(path: Path) -> ProtocolSpec:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(
            f"cannot read the protocol spec {path}: {exc.strerror}; it is firmware/protocol.yaml "
            "in the tvsd source tree and tvsd/hw/mcu/protocol.yaml in an installed wheel: "
            "reinstall tvsd from a wheel built by `pip wheel` (setup.py copies it in)"
        ) from exc
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from exc
    return parse_spec(doc, path)
