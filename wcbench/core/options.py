"""Declared options: name, type, range and meaning of every setting a user can give, checked up front.

A method declares its options as an :class:`Option` schema (``options`` on its class); the training
settings and the editor's appearance tables are schemas derived from their dataclass or preset file
(:func:`options_from_dataclass`), so a schema cannot drift from the constructor it feeds.
:func:`validate_options` checks a dict of values against a schema before any work starts and refuses
the first bad one with one line naming the option, the value and what is allowed
(docs/guide.md, "Method options").
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
import numbers
import re
import typing
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from wcbench.core.errors import InputError

__all__ = ["Option", "OptionError", "Range", "attribute_docs", "describe_value", "options_from_dataclass",
           "schema_lines", "validate_options"]

#: Kinds of value an option takes.
KINDS = ("int", "float", "bool", "str", "ints", "floats", "table", "custom")


class OptionError(InputError):
    """A value an option does not allow, or an option a schema does not declare.

    Attributes
    ----------
    path : str
        The option's dotted name (``settings.iterations``).
    """

    def __init__(self, message: str, *, path: str):
        super().__init__(message)
        self.path = path


@dataclass(frozen=True)
class Range:
    """Bounds of a number: ``low`` and ``high`` (``None``: unbounded), each inclusive unless ``*_open``."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False

    def contains(self, x: float) -> bool:
        """Whether ``x`` lies in the range."""
        if self.low is not None and (x <= self.low if self.low_open else x < self.low):
            return False
        return not (self.high is not None and (x >= self.high if self.high_open else x > self.high))

    def text(self) -> str:
        """``>= 1``, ``> 0``, ``in [0, 1]``, ``in (0, 4]`` or ``""`` (unbounded)."""
        if self.low is not None and self.high is not None:
            return (f"in {'(' if self.low_open else '['}{_num(self.low)}, {_num(self.high)}"
                    f"{')' if self.high_open else ']'}")
        if self.low is not None:
            return f"{'>' if self.low_open else '>='} {_num(self.low)}"
        if self.high is not None:
            return f"{'<' if self.high_open else '<='} {_num(self.high)}"
        return ""


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else f"{x:g}"


@dataclass(frozen=True)
class Option:
    """One declared option.

    Attributes
    ----------
    name : str
        Key (one level; a table's keys are options of their own).
    kind : str
        ``int``, ``float``, ``bool``, ``str``, ``ints``/``floats`` (a list of numbers), ``table``
        (a dict of the options in ``table``) or ``custom`` (``check`` decides).
    doc : str
        What it means (one line, shown by ``wcbench methods show``).
    default : any
        The value when it is not given (shown only).
    range : Range, optional
        Bounds of a number, or of every number of a list.
    choices : tuple, optional
        The values a ``str`` option takes.
    length : int, optional
        The length of an ``ints``/``floats`` list (``None``: any length).
    nullable : bool
        ``null`` (``None``) is allowed: the default behaviour.
    table : mapping of str to Option, optional
        The keys of a ``table`` option.
    check : callable, optional
        For ``custom``: returns the value to use or raises ``ValueError`` whose message says what is
        allowed.
    allowed : str
        What a ``custom`` option allows (for its errors and the listing).
    renamed_to : str
        Set on an option's old name, kept for one release: the new name. The value is checked by
        this option (its messages name the old name, as given) and handed on under the new name,
        with a deprecation warning; both names given together are refused.
    """

    name: str
    kind: str
    doc: str
    default: Any = None
    range: Range | None = None
    choices: tuple[Any, ...] = ()
    length: int | None = None
    nullable: bool = False
    table: Mapping[str, Option] | None = None
    check: Callable[[Any], Any] | None = field(default=None, compare=False)
    allowed: str = ""
    renamed_to: str = ""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"option {self.name}: kind must be one of {', '.join(KINDS)}, got {self.kind!r}")
        if (self.kind == "table") != (self.table is not None):
            raise ValueError(f"option {self.name}: a table option and only it has a table")
        if (self.kind == "custom") != (self.check is not None):
            raise ValueError(f"option {self.name}: a custom option and only it has a check")

    def allowed_text(self) -> str:
        """What the option allows, in words (``an integer >= 1``)."""
        bounds = f" {self.range.text()}" if self.range is not None and self.range.text() else ""
        if self.kind == "int":
            text = f"an integer{bounds}"
        elif self.kind == "float":
            text = f"a number{bounds}"
        elif self.kind == "bool":
            text = "true or false"
        elif self.kind == "str":
            text = ("one of " + ", ".join(repr(c) for c in self.choices)) if self.choices else "a text"
        elif self.kind in ("ints", "floats"):
            what = "integers" if self.kind == "ints" else "numbers"
            count = f"{self.length} " if self.length is not None else ""
            text = f"a list of {count}{what}{bounds}" + (", e.g. [1, 2]" if self.length is None else "")
        elif self.kind == "table":
            assert self.table is not None
            keys = list(self.table)
            shown = ", ".join(keys) if len(keys) <= 6 else f"{', '.join(keys[:3])}... ({len(keys)} keys)"
            text = f"a table of keys {shown}, given as {self.name}.KEY=VALUE"
        else:
            text = self.allowed or "see `wcbench methods show`"
        return text + (" or null" if self.nullable else "")


def describe_value(value: Any) -> str:
    """``value`` as the command line spells it (JSON where it can be), at most 60 characters."""
    try:
        text = json.dumps(value) if not isinstance(value, str) else value
    except (TypeError, ValueError):
        text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _refuse(prefix: str, path: str, value: Any, allowed: str) -> OptionError:
    return OptionError(f"{prefix}{path}={describe_value(value)}: expected {allowed}", path=path)


def _number(value: Any, *, integer: bool) -> float | int | None:
    """``value`` as an int or finite float, or ``None`` when it is no such number (bools are not)."""
    if isinstance(value, bool):
        return None
    if integer:
        return int(value) if isinstance(value, numbers.Integral) else None
    if isinstance(value, numbers.Real) and math.isfinite(float(value)):
        return float(value)
    return None


def _check_one(opt: Option, value: Any, path: str, prefix: str) -> Any:
    """The value to use for option ``opt`` given ``value``, or :class:`OptionError`."""
    if value is None:
        if opt.nullable:
            return None
        raise _refuse(prefix, path, value, opt.allowed_text())
    if opt.kind in ("int", "float"):
        x = _number(value, integer=opt.kind == "int")
        if x is None or (opt.range is not None and not opt.range.contains(x)):
            raise _refuse(prefix, path, value, opt.allowed_text())
        return x
    if opt.kind == "bool":
        if not isinstance(value, bool):
            raise _refuse(prefix, path, value, opt.allowed_text())
        return value
    if opt.kind == "str":
        if not isinstance(value, str) or (opt.choices and value not in opt.choices):
            raise _refuse(prefix, path, value, opt.allowed_text())
        return value
    if opt.kind in ("ints", "floats"):
        if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, typing.Sequence):
            raise _refuse(prefix, path, value, opt.allowed_text())
        items = [_number(v, integer=opt.kind == "ints") for v in value]
        if (opt.length is not None and len(items) != opt.length) or any(
                x is None or (opt.range is not None and not opt.range.contains(x)) for x in items):
            raise _refuse(prefix, path, value, opt.allowed_text())
        return tuple(items)
    if opt.kind == "table":
        assert opt.table is not None
        if not isinstance(value, Mapping):
            raise _refuse(prefix, path, value, opt.allowed_text())
        return validate_options(opt.table, value, prefix=prefix, path=path, owner=path)
    assert opt.check is not None
    try:
        return opt.check(value)
    except (TypeError, ValueError) as exc:  # the check's message says what is wrong and what is allowed
        message = str(exc).splitlines()[0] if str(exc) else f"expected {opt.allowed_text()}"
        raise OptionError(f"{prefix}{path}={describe_value(value)}: {message}", path=path) from None


def _warn_renamed(old: str, new: str, *, prefix: str) -> None:
    # attributed to the caller of get_method (here <- validate_options <- validate_method_options <- get_method)
    warnings.warn(f"{prefix}{old} is deprecated, use {new}", DeprecationWarning, stacklevel=5)


def validate_options(schema: Mapping[str, Option], values: Mapping[str, Any], *, prefix: str = "",
                     path: str = "", owner: str = "",
                     deprecated: Callable[[str, str], None] | None = None) -> dict[str, Any]:
    """Check ``values`` against ``schema``; return them converted (lists of numbers as tuples), an
    option given by its old name (:attr:`Option.renamed_to`) under its new one.

    Parameters
    ----------
    schema : mapping of str to Option
    values : mapping of str to any
        Only the options given (the others keep their defaults).
    prefix : str
        Starts every message (``"physical-editor option "``).
    path : str
        Dotted name of the table ``values`` is (``settings``); ``""`` at the top.
    owner : str
        Who takes the options, for an unknown key's message (a method's name).
    deprecated : callable, optional
        Called as ``deprecated(old, new)`` (dotted names) for each option given by its old name,
        once its value is checked; default: a :class:`DeprecationWarning` saying
        ``PREFIX OLD is deprecated, use NEW`` (the command line prints its own line instead).

    Returns
    -------
    dict

    Raises
    ------
    OptionError
        On the first unknown key (with close names) or value the option does not allow, in one
        line: ``PREFIX PATH=VALUE: expected ALLOWED``; on an option given by both its old and its
        new name (both named).
    """
    out: dict[str, Any] = {}
    for key, value in values.items():
        full = f"{path}.{key}" if path else str(key)
        opt = schema.get(key)
        if opt is None:
            close = difflib.get_close_matches(str(key), [k for k, o in schema.items() if not o.renamed_to], n=2,
                                              cutoff=0.6)
            hint = f" (did you mean {' or '.join(close)}?)" if close else ""
            where = f"{owner} takes" if owner else "there is"
            known = ", ".join(k for k, o in schema.items() if not o.renamed_to) or "none"
            raise OptionError(f"{prefix}{full}={describe_value(value)}: {where} no option {key}{hint}; "
                              f"it takes: {known}", path=full)
        checked = _check_one(opt, value, full, prefix)
        if opt.renamed_to:
            new = f"{path}.{opt.renamed_to}" if path else opt.renamed_to
            if opt.renamed_to in values:
                raise OptionError(f"{prefix}{full} and {new} both given: {full} is the deprecated name of {new}; "
                                  f"give {new} only", path=full)
            if deprecated is not None:
                deprecated(full, new)
            else:
                _warn_renamed(full, new, prefix=prefix)
            key = opt.renamed_to
        out[key] = checked
    return out


def schema_lines(schema: Mapping[str, Option], *, path: str = "") -> list[str]:
    """One line per option (tables flattened to ``table.key``): name, allowed values, default, meaning."""
    lines = []
    for name, opt in schema.items():
        full = f"{path}.{name}" if path else name
        if opt.renamed_to:
            lines.append(f"{full}  deprecated name of {opt.renamed_to} (accepted for one release)")
            continue
        if opt.kind == "table" and opt.table is not None:
            lines.append(f"{full}  (table)  {opt.doc}")
            lines.extend(schema_lines(opt.table, path=full))
            continue
        default = "" if opt.default is None and not opt.nullable else f"  [default: {describe_value(opt.default)}]"
        lines.append(f"{full}  {opt.allowed_text()}{default}  {opt.doc}")
    return lines


def attribute_docs(cls: type) -> dict[str, str]:
    """The first sentence of each entry of the numpydoc ``Attributes`` section of ``cls``'s docstring
    (``a, b : int`` entries give both names the same text)."""
    lines = (cls.__doc__ or "").splitlines()
    out: dict[str, str] = {}
    try:
        start = next(i for i, ln in enumerate(lines) if ln.strip() == "Attributes") + 2
    except StopIteration:
        return out
    names: list[str] = []
    text: list[str] = []
    indent = None

    def flush() -> None:
        sentence = " ".join(text).strip()
        sentence = re.split(r"(?<=[^.]\.)\s", sentence, maxsplit=1)[0] if sentence else ""
        sentence = re.sub(r":\w+:`~?\.?([^`]+)`", r"\1", sentence).replace("``", "")  # reST roles, as plain text
        for n in names:
            out[n] = sentence

    for line in lines[start:]:
        stripped = line.strip()
        if not stripped:
            continue
        level = len(line) - len(line.lstrip())
        if indent is None:
            indent = level
        if level < indent or (level == indent and set(stripped) == {"-"}):
            break
        if level == indent:
            flush()
            names = [n.strip() for n in stripped.split(":")[0].split(",")]
            text = []
        else:
            text.append(stripped)
    flush()
    return out


def _kind_of(hint: Any, default: Any) -> tuple[str, int | None]:
    """(kind, length) of a dataclass field's type hint."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint is bool:
        return "bool", None
    if hint is int:
        return "int", None
    if hint is float:
        return "float", None
    if hint is str:
        return "str", None
    if origin is tuple and args:
        item = args[0]
        kind = "ints" if item is int else "floats"
        return kind, None if (len(args) == 2 and args[1] is Ellipsis) else len(args)
    if origin is dict and isinstance(default, Mapping):
        return "table", None
    raise ValueError(f"no option kind for the type {hint!r}")


def options_from_dataclass(cls: type, *, ranges: Mapping[str, Range], skip: tuple[str, ...] = (),
                           choices: Mapping[str, tuple[Any, ...]] | None = None,
                           docs: Mapping[str, str] | None = None) -> dict[str, Option]:
    """The options of a dataclass's fields: kind from the type hint, default from the field, meaning
    from the ``Attributes`` section of its docstring (or ``docs``), bounds from ``ranges``.

    A ``dict[str, float]`` field becomes a table of its default's keys. Every number (and every
    number of a table or list) must have a range, and every option a meaning, so that a field
    added without either fails here rather than going unchecked.

    Raises
    ------
    ValueError
        A numeric field without a range, a field without a meaning, a range of no field.
    """
    hints = typing.get_type_hints(cls)
    meanings = {**attribute_docs(cls), **(docs or {})}
    out: dict[str, Option] = {}
    for f in dataclasses.fields(cls):
        if f.name in skip:
            continue
        default = f.default if f.default is not dataclasses.MISSING else (
            f.default_factory() if f.default_factory is not dataclasses.MISSING else None)
        kind, length = _kind_of(hints[f.name], default)
        doc = meanings.get(f.name, "")
        if not doc:
            raise ValueError(f"{cls.__name__}.{f.name}: no meaning (document it under Attributes)")
        if kind == "table":
            assert isinstance(default, Mapping)
            table = {}
            for key, value in default.items():
                sub = f"{f.name}.{key}"
                if sub not in ranges:
                    raise ValueError(f"{cls.__name__}.{sub}: no declared range")
                table[key] = Option(key, "float" if isinstance(value, float) else "int", f"{doc} ({key})",
                                    default=value, range=ranges[sub])
            out[f.name] = Option(f.name, "table", doc, table=table)
            continue
        numeric = kind in ("int", "float", "ints", "floats")
        if numeric and f.name not in ranges:
            raise ValueError(f"{cls.__name__}.{f.name}: no declared range")
        out[f.name] = Option(f.name, kind, doc, default=default, range=ranges.get(f.name), length=length,
                             choices=(choices or {}).get(f.name, ()))
    declared = {k.split(".")[0] for k in ranges}
    stray = sorted(declared - {f.name for f in dataclasses.fields(cls)})
    if stray:
        raise ValueError(f"{cls.__name__}: ranges of no field: {stray}")
    return out
