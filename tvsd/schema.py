"""Typed, range-checked reading of YAML into frozen dataclasses, with file and line in every error.

Every config section is a frozen dataclass whose fields carry their own rule (see `option`): the
unit, the range, the allowed choices and one line of doc. `build` walks the YAML mapping against
the dataclass, rejects unknown keys (suggesting the closest known one), wrong types and values out
of range — Klipper's `configfile.py` typed getters are the model (STYLE.md §2).
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import stat
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from tvsd.errors import ConfigError, UsageError


def option(
    default: Any = dataclasses.MISSING,
    *,
    doc: str = "",
    unit: str = "",
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
    choices: tuple[str, ...] | None = None,
) -> Any:
    """A dataclass field with its validation rule."""
    meta = {"doc": doc, "unit": unit, "gt": gt, "ge": ge, "lt": lt, "le": le, "choices": choices}
    if isinstance(default, (list, dict)):
        frozen = tuple(default) if isinstance(default, list) else default
        return field(default_factory=lambda: frozen, metadata=meta)
    return field(default=default, metadata=meta)


class FieldError(UsageError):
    """A value breaks a settings dataclass's own rule (checked in its `__post_init__`): names the
    key, so a config file's error points at that key's line."""

    def __init__(self, key: str, problem: str) -> None:
        super().__init__(f"{key}: {problem}")
        self.key = key
        self.problem = problem


class LinedDict(dict[str, Any]):
    """A YAML mapping that remembers the line of each key (1-based) and of itself."""

    line: int = 0
    key_lines: dict[str, int]


MAX_DEPTH = 16  # the deepest config is 3 levels: more is a mistake (or an attack on the stack)
# Beyond any physical quantity in the config: a key without its own upper bound still refuses
# `kb: 2**64` (it passed --check, then the simulation overflowed to null).
DEFAULT_MAX = 1e12


class _LineLoader(yaml.SafeLoader):
    """SafeLoader that remembers lines, refuses duplicate keys and deep nesting, and reads
    numbers in YAML 1.2's spelling too (`6e-5`, `1E3`: strings to YAML 1.1)."""

    _depth = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        self._depth += 1
        try:
            if self._depth > MAX_DEPTH:
                mark = self.peek_event().start_mark
                raise yaml.composer.ComposerError(
                    None, None, f"nested more than {MAX_DEPTH} levels deep (a config has 3)", mark
                )
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def _construct_mapping(loader: _LineLoader, node: yaml.MappingNode) -> LinedDict:
    loader.flatten_mapping(node)
    result = LinedDict()
    result.line = node.start_mark.line + 1
    result.key_lines = {}
    for key_node, value_node in node.value:
        key = str(loader.construct_object(key_node, deep=True))
        if key in result.key_lines:
            raise yaml.constructor.ConstructorError(
                None,
                None,
                f"duplicate key '{key}' (first at line {result.key_lines[key]}): keep one",
                key_node.start_mark,
            )
        result[key] = loader.construct_object(value_node, deep=True)
        result.key_lines[key] = key_node.start_mark.line + 1
    return result


_LineLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)
# YAML 1.2 floats that 1.1 reads as strings: an exponent without a dot or without a sign.
_LineLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."),
)


MAX_CONFIG_BYTES = 1 << 20


def load_yaml(path: Path) -> LinedDict:
    """Read a YAML file whose top level is a mapping; errors name the file and line."""
    try:
        st = path.stat()
        if stat.S_ISREG(st.st_mode) and st.st_size > MAX_CONFIG_BYTES:
            raise ConfigError(f"{path}: {st.st_size} bytes; a config is a few KB: is this the right file?")
        if not stat.S_ISREG(st.st_mode) and not stat.S_ISDIR(st.st_mode):  # /dev/zero was read forever
            raise ConfigError(f"{path}: not a regular file (a device or a pipe); give the YAML file")
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such config file; check the path (see config/ for examples)") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory, not a config file; give the YAML file in it") from None
    except PermissionError:
        raise ConfigError(
            f"{path}: cannot read config file: permission denied; check its mode, or run as a user who may"
        ) from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not UTF-8 text; a config is a YAML text file") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read config file: {exc.strerror}") from exc
    try:
        data = yaml.load(text, Loader=_LineLoader)
    except RecursionError:  # a flow collection nested past the stack, before MAX_DEPTH: no mark
        raise ConfigError(f"{path}:1: nested too deep (a config has 3 levels); fix the file") from None
    except ValueError as exc:  # e.g. an integer of more than 4300 digits (Python's int limit)
        raise ConfigError(f"{path}: a value YAML cannot read: {str(exc)[:80]}; fix it") from None
    except yaml.reader.ReaderError as exc:  # a control character: no line mark, a byte position
        line = text.count("\n", 0, max(exc.position, 0)) + 1
        raise ConfigError(
            f"{path}:{line}: not valid YAML (control character {chr(exc.character)!r}); remove it"
        ) from exc
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark is not None else str(path)
        problem = " ".join(str(getattr(exc, "problem", None) or exc).split())  # one line, always
        raise ConfigError(f"{where}: not valid YAML ({problem}); fix the syntax there") from exc
    if data is None:
        data = LinedDict()
        data.line, data.key_lines = 1, {}
    if not isinstance(data, LinedDict):
        raise ConfigError(
            f"{path}:1: expected a mapping of sections at the top level, got {type(data).__name__}"
        )
    return data


@dataclass(frozen=True)
class Where:
    """Where a value came from, for error messages."""

    path: Path
    line: int
    key: str  # dotted, e.g. "plant.J"

    def error(self, problem: str) -> ConfigError:
        return ConfigError(f"{self.path}:{self.line}: {self.key}: {problem}")


def build(cls: type, data: Any, where: Where) -> Any:
    """Build dataclass `cls` from a YAML mapping, checking every key against its rule."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise where.error(f"expected a section (a mapping of keys), got {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    lines = getattr(data, "key_lines", {})
    for key in data:
        if key not in fields:
            close = difflib.get_close_matches(key, fields, n=1)
            hint = f"did you mean '{close[0]}'?" if close else f"known keys: {', '.join(fields)}"
            line = lines.get(key, where.line)
            raise Where(where.path, line, _join(where.key, key)).error(f"unknown key; {hint}")
    values: dict[str, Any] = {}
    for name, f in fields.items():
        sub = Where(where.path, lines.get(name, where.line), _join(where.key, name))
        if name not in data:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise where.error(f"missing required key '{name}' ({f.metadata.get('doc', '')})")
            continue
        values[name] = convert(hints[name], data[name], sub, f.metadata)
    try:
        return cls(**values)
    except ConfigError:
        raise
    except FieldError as exc:
        line = lines.get(exc.key, where.line)
        raise Where(where.path, line, _join(where.key, exc.key)).error(exc.problem) from None
    except UsageError as exc:
        # A rule across keys (e.g. phi_min_deg < phi_max_deg), checked by the dataclass itself:
        # point at the section, since no single key is wrong on its own.
        raise ConfigError(f"{where.path}:{where.line}: {exc}") from None


def _join(prefix: str, key: str) -> str:
    return f"{prefix}.{key}" if prefix else key


def convert(tp: Any, value: Any, where: Where, meta: typing.Mapping[str, Any]) -> Any:
    """Convert one YAML value to type `tp` and check it against the field's rule."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        (inner,) = [a for a in args if a is not type(None)]
        return convert(inner, value, where, meta)
    if dataclasses.is_dataclass(tp):
        return build(tp, value, where)  # type: ignore[arg-type]
    if origin is tuple:
        if not isinstance(value, list):
            raise where.error(f"expected a list, got {_shown_any(value)}")
        item_type = args[0]
        return tuple(
            convert(item_type, v, Where(where.path, where.line, f"{where.key}[{i}]"), meta)
            for i, v in enumerate(value)
        )
    if tp is bool:
        if not isinstance(value, bool):
            raise where.error(f"expected true or false, got {_shown_any(value)}")
        return value
    if tp is Path:
        if not isinstance(value, str) or not value:
            raise where.error(f"expected a file path, got {_shown_any(value)}")
        return Path(value)
    if tp is str:
        choices = meta.get("choices")
        if value is False and choices and "off" in choices:
            value = "off"  # YAML 1.1 reads a bare `off` (or no, false) as false: the choice meant
        if not isinstance(value, str):
            raise where.error(f"expected text, got {_shown_any(value)}")
        if choices and value not in choices:
            raise where.error(f"expected one of {', '.join(choices)}, got {_shown_any(value)}")
        return value
    if tp in (int, float):
        return _number(tp, value, where, meta)
    raise TypeError(f"schema type {tp!r} not supported")  # a bug in a schema, not a user error


def _number(tp: type, value: Any, where: Where, meta: typing.Mapping[str, Any]) -> float | int:
    unit = f" {meta['unit']}" if meta.get("unit") else ""
    kind = "a whole number" if tp is int else "a number"
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise where.error(f"expected {kind}{unit}, got {_shown_any(value)}")
    if tp is int and isinstance(value, float) and not value.is_integer():
        raise where.error(f"expected {kind}{unit}, got {_shown_any(value)}")
    if isinstance(value, int) and abs(value) > 10**300:  # float() of it would overflow
        raise where.error(f"must be within ±{DEFAULT_MAX:g}{unit}, got {_shown(value)}")
    number = tp(value)
    problem = _number_problem(number, value, meta)
    if problem is not None:
        raise where.error(problem)
    return number


def _number_problem(number: float, value: Any, meta: typing.Mapping[str, Any]) -> str | None:
    """What is wrong with `number` under the field's rule (`value`: as the user wrote it)."""
    unit = f" {meta['unit']}" if meta.get("unit") else ""
    if not math.isfinite(number):
        return f"expected a finite number{unit}, got {_shown_any(value)}"
    for bound, ok, text in (
        ("gt", lambda b: number > b, "above"),
        ("ge", lambda b: number >= b, "at least"),
        ("lt", lambda b: number < b, "below"),
        ("le", lambda b: number <= b, "at most"),
    ):
        limit = meta.get(bound)
        if limit is not None and not ok(limit):
            return f"must be {text} {limit:g}{unit}, got {_shown(value)}"
    if meta.get("le") is None and meta.get("lt") is None and abs(number) > DEFAULT_MAX:
        return f"must be within ±{DEFAULT_MAX:g}{unit} (no physical value is larger), got {_shown(value)}"
    return None


def _shown_any(value: Any) -> str:
    if isinstance(value, int) and not isinstance(value, bool):
        return _shown(value)
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _shown(value: Any) -> str:
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > 10**15:
        return f"{float(value):.3g}" if abs(value) < 10**300 else "a number of hundreds of digits"
    return repr(value)


def check(obj: Any) -> None:
    """Check a settings dataclass built in code (an API request, a command-line value) against
    the same `option` rules its YAML section is checked by: UsageError "key: problem".

    Call it from `__post_init__`: then the rules hold for every instance, however it was made."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        meta = f.metadata
        problem = None
        if isinstance(value, bool):
            continue
        if isinstance(value, (int, float)):
            problem = _number_problem(value, value, meta)
        elif isinstance(value, str) and meta.get("choices") and value not in meta["choices"]:
            problem = f"expected one of {', '.join(meta['choices'])}, got {_shown_any(value)}"
        if problem is not None:
            raise FieldError(f.name, problem)
