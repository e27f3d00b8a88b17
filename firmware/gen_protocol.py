#!/usr/bin/env python3
"""Generate the firmware's C protocol header from firmware/protocol.yaml.

protocol.yaml is the single source of truth; this script only transcribes it. The output
(protocol_gen.h) holds ids, payload sizes, packed field offsets, pack/unpack helpers, the
X-macro lists the dispatch table is built from, and the command-table hash the host checks.

Usage: gen_protocol.py [--out build/protocol_gen.h] [--print-canonical] [protocol.yaml]
Needs only the standard library and PyYAML.
"""

from __future__ import annotations

import argparse
import sys
import zlib
from dataclasses import dataclass
from pathlib import Path

import yaml

HERE = Path(__file__).resolve().parent

# (size in bytes, C type, signed) for every wire type protocol.yaml may use.
TYPES: dict[str, tuple[int, str]] = {
    "u8": (1, "uint8_t"),
    "i8": (1, "int8_t"),
    "u16": (2, "uint16_t"),
    "i16": (2, "int16_t"),
    "u32": (4, "uint32_t"),
    "i32": (4, "int32_t"),
}


@dataclass(frozen=True)
class Field:
    name: str
    type: str
    offset: int

    @property
    def size(self) -> int:
        return TYPES[self.type][0]

    @property
    def ctype(self) -> str:
        return TYPES[self.type][1]


@dataclass(frozen=True)
class Message:
    id: int
    name: str
    dir: str
    fields: tuple[Field, ...]

    @property
    def size(self) -> int:
        return sum(f.size for f in self.fields)


class SpecError(ValueError):
    """protocol.yaml breaks a rule the generator relies on."""


def load(path: Path) -> tuple[dict[str, object], list[Message]]:
    spec = yaml.safe_load(path.read_text())
    max_payload = int(spec["max_payload"])
    messages: list[Message] = []
    seen_ids: set[int] = set()
    seen_names: set[str] = set()
    for raw in spec["messages"]:
        mid, name, direction = int(raw["id"]), str(raw["name"]), str(raw["dir"])
        where = f"{path}: message {name!r} (id 0x{mid:02X})"
        if mid in seen_ids or name in seen_names:
            raise SpecError(f"{where}: duplicate id or name")
        if direction not in ("h2m", "m2h"):
            raise SpecError(f"{where}: dir must be h2m or m2h, got {direction!r}")
        if (direction == "h2m") != (0x01 <= mid <= 0x7F):
            raise SpecError(f"{where}: h2m ids are 0x01..0x7F, m2h ids 0x80..0xFF")
        offset = 0
        fields: list[Field] = []
        for fname, ftype in raw["fields"]:
            if not isinstance(fname, str) or not fname.isidentifier():
                # YAML 1.1 reads a bare on/off/yes/no as a boolean: quote such names.
                raise SpecError(f"{where}: field name {fname!r} is not an identifier (quote it in the YAML)")
            if ftype not in TYPES:
                raise SpecError(f"{where}: field {fname!r} has unknown type {ftype!r}")
            fields.append(Field(str(fname), str(ftype), offset))
            offset += TYPES[ftype][0]
        if offset > max_payload:
            raise SpecError(f"{where}: payload {offset} B exceeds max_payload {max_payload}")
        seen_ids.add(mid)
        seen_names.add(name)
        messages.append(Message(mid, name, direction, tuple(fields)))
    messages.sort(key=lambda m: m.id)
    return spec, messages


def canonical_text(messages: list[Message]) -> str:
    """The text whose CRC-32 is the command-table hash (rule in protocol.yaml's header)."""
    lines = []
    for m in sorted(messages, key=lambda m: m.id):
        fields = ",".join(f"{f.name}:{f.type}" for f in m.fields)
        lines.append(f"{m.id}:{m.name}:{fields}\n")
    return "".join(lines)


def table_hash(messages: list[Message]) -> int:
    return zlib.crc32(canonical_text(messages).encode("ascii")) & 0xFFFFFFFF


def _c_ident(name: str) -> str:
    ident = "".join(ch if ch.isalnum() else "_" for ch in name).upper()
    if not ident or ident[0].isdigit():
        raise SpecError(f"name {name!r} does not make a C identifier")
    return ident


def _message_block(m: Message) -> list[str]:
    up = m.name.upper()
    out = [f"/* {m.name} ({m.dir}) */",
           f"#define MSG_{up}_ID 0x{m.id:02X}u",
           f"#define MSG_{up}_LEN {m.size}u"]
    out += [f"#define MSG_{up}_{f.name.upper()}_OFF {f.offset}u" for f in m.fields]
    if not m.fields:
        return [*out, ""]
    out.append("typedef struct {")
    out += [f"    {f.ctype} {f.name};" for f in m.fields]
    out.append(f"}} msg_{m.name}_t;")
    out.append(f"static inline void msg_{m.name}_pack(uint8_t *p, const msg_{m.name}_t *m)")
    out.append("{")
    for f in m.fields:
        bits = f.size * 8
        out.append(f"    proto_put_u{bits}(p + {f.offset}, (uint{bits}_t)m->{f.name});")
    out.append("}")
    out.append(f"static inline void msg_{m.name}_unpack(const uint8_t *p, msg_{m.name}_t *m)")
    out.append("{")
    for f in m.fields:
        bits = f.size * 8
        out.append(f"    m->{f.name} = ({f.ctype})proto_get_u{bits}(p + {f.offset});")
    out.append("}")
    out.append("")
    return out


def render(spec: dict[str, object], messages: list[Message]) -> str:
    faults = {int(k): str(v) for k, v in dict(spec["fault_codes"]).items()}  # type: ignore[call-overload]
    channels = {int(k): str(v) for k, v in dict(spec["pulse_channels"]).items()}  # type: ignore[call-overload]
    boards = {int(k): str(v) for k, v in dict(spec["boards"]).items()}  # type: ignore[call-overload]
    h = table_hash(messages)
    out = [
        "/* GENERATED by firmware/gen_protocol.py from firmware/protocol.yaml. Do not edit. */",
        "#ifndef PROTOCOL_GEN_H",
        "#define PROTOCOL_GEN_H",
        "#include <stdint.h>",
        "",
        f"#define PROTOCOL_VERSION {int(spec['version'])}u",  # type: ignore[call-overload]
        f"#define PROTOCOL_TABLE_HASH 0x{h:08X}ul",
        f"#define PROTO_SYNC 0x{int(spec['sync']):02X}u",  # type: ignore[call-overload]
        f"#define PROTO_MAX_PAYLOAD {int(spec['max_payload'])}u",  # type: ignore[call-overload]
        "#define PROTO_OVERHEAD 6u /* SYNC LEN SEQ ID .. CRC16 */",
        "#define PROTO_MAX_FRAME (PROTO_MAX_PAYLOAD + PROTO_OVERHEAD)",
        "",
        "/* Little-endian, byte-wise: alignment and host endianness do not matter. */",
        "static inline void proto_put_u8(uint8_t *p, uint8_t v) { p[0] = v; }",
        "static inline void proto_put_u16(uint8_t *p, uint16_t v)",
        "{ p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }",
        "static inline void proto_put_u32(uint8_t *p, uint32_t v)",
        "{ proto_put_u16(p, (uint16_t)v); proto_put_u16(p + 2, (uint16_t)(v >> 16)); }",
        "static inline uint8_t proto_get_u8(const uint8_t *p) { return p[0]; }",
        "static inline uint16_t proto_get_u16(const uint8_t *p)",
        "{ return (uint16_t)(p[0] | ((uint16_t)p[1] << 8)); }",
        "static inline uint32_t proto_get_u32(const uint8_t *p)",
        "{ return proto_get_u16(p) | ((uint32_t)proto_get_u16(p + 2) << 16); }",
        "",
    ]
    for m in messages:
        out += _message_block(m)
    for direction in ("h2m", "m2h"):
        out.append(f"/* X(id, name, LEN) per {direction} message: tables are built from it. */")
        out.append(f"#define PROTO_{direction.upper()}_LIST(X) \\")
        out += [f"    X(0x{m.id:02X}u, {m.name}, {m.size}u) \\"
                for m in messages if m.dir == direction]
        out.append("")
    out += [f"#define FAULT_{_c_ident(n)} {c}u" for c, n in sorted(faults.items())]
    out += [f"#define PULSE_CH_{_c_ident(n)} {c}u" for c, n in sorted(channels.items())]
    out += [f"#define BOARD_ID_{_c_ident(n)} {c}u" for c, n in sorted(boards.items())]
    out += ["", "#endif /* PROTOCOL_GEN_H */", ""]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("spec", nargs="?", type=Path, default=HERE / "protocol.yaml")
    ap.add_argument("--out", type=Path, default=HERE / "build" / "protocol_gen.h")
    ap.add_argument("--print-canonical", action="store_true",
                    help="print the canonical command-table text and its hash, write nothing")
    args = ap.parse_args(argv)
    try:
        spec, messages = load(args.spec)
    except (SpecError, KeyError, TypeError, ValueError) as exc:
        print(f"gen_protocol: {args.spec}: {exc}", file=sys.stderr)
        return 2
    if args.print_canonical:
        sys.stdout.write(canonical_text(messages))
        print(f"table_hash=0x{table_hash(messages):08X}")
        return 0
    text = render(spec, messages)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    # Rewrite only on change so make does not rebuild everything for nothing.
    if not args.out.exists() or args.out.read_text() != text:
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
